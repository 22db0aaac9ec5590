"""Ray, when it is installed (``pip install 'seg2pose[scale]'``): the module, and a ``map`` whose items
run as Ray tasks. Batch runs (``seg2pose.batch``) and the training fan-out (``s2p train
--parallel``) both use it; training is handed the mapper, so it knows nothing of Ray."""

from __future__ import annotations

from seg2pose.core.errors import S2PError

MAX_RETRIES = 3  # Ray retries of a task whose worker died


def import_ray():
    """The ``ray`` module, or None when Ray is not installed. Imported here, on first use:
    importing Ray takes seconds and most commands never need it."""
    try:
        import ray
    except ImportError:
        return None
    return ray


def ray_available() -> bool:
    return import_ray() is not None


def start_ray(ray, address: str | None, num_cpus: int | None, **kwargs):
    """``ray.init`` for a command: the cluster at ``address`` when the user named one, else a
    Ray of this process's own (address "local", ``num_cpus`` CPUs, default all) that ends with
    it, never a cluster that another command or user started on this machine (which a plain
    ``ray.init()`` would join). ``kwargs`` go to ``ray.init``; returns its context."""
    return ray.init(address=address or "local", num_cpus=None if address else num_cpus, **kwargs)


def ray_map(address: str | None = None, num_cpus: int | None = None):
    """A ``map(fn, items)`` that runs each item as a Ray task (retried when its worker dies)
    and returns the results in order: for ``train_scene(map_groups=...)`` (``s2p train
    --parallel/--address``). Starts a Ray of its own with ``num_cpus`` CPUs or joins the
    cluster at ``address`` (``start_ray``), unless this process has started Ray already."""
    ray = import_ray()
    if ray is None:
        raise S2PError("parallel training needs Ray: pip install 'seg2pose[scale]'")

    def mapper(fn, items):
        if not ray.is_initialized():
            start_ray(ray, address, num_cpus, log_to_driver=True)
        remote = ray.remote(max_retries=MAX_RETRIES)(fn)
        return ray.get([remote.remote(x) for x in items])

    return mapper
