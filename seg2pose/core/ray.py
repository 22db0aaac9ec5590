"""Ray, when it is installed (``pip install 's2p[scale]'``): the module, and a ``map`` whose items
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


def ray_map(address: str | None = None, num_cpus: int | None = None):
    """A ``map(fn, items)`` that runs each item as a Ray task (retried when its worker dies)
    and returns the results in order: for ``train_scene(map_groups=...)`` (``s2p train
    --parallel/--address``). Starts a local Ray (``num_cpus``) or joins ``address`` unless Ray
    is running already."""
    ray = import_ray()
    if ray is None:
        raise S2PError("parallel training needs Ray: pip install 's2p[scale]'")

    def mapper(fn, items):
        if not ray.is_initialized():
            ray.init(address=address, num_cpus=None if address else num_cpus, log_to_driver=True)
        remote = ray.remote(max_retries=MAX_RETRIES)(fn)
        return ray.get([remote.remote(x) for x in items])

    return mapper
