"""Everything Rerun: entity layout, blueprint, logging, viewer control, MCAP export.

Public API (imports are lazy so that ``import s2p_review`` does not load rerun)::

    record(scene, runs, rrd_path=None, *, spawn=False, connect=None, frames=None, force=False)
    export_mcap(scene, run_dir, out_path, force=False)
    import_mcap(path, out_dir, force=False)
    take_screenshot(rrd_path, png_path, *, frame=None, force=False)
"""

from __future__ import annotations

__all__ = ["record", "export_mcap", "import_mcap", "take_screenshot", "RecordOptions"]


def __getattr__(name: str):
    if name in ("record", "RecordOptions"):
        from s2p_review import recording as _r

        return getattr(_r, name)
    if name in ("export_mcap", "import_mcap"):
        from s2p_review import mcap_io

        return getattr(mcap_io, name)
    if name == "take_screenshot":
        from s2p_review.viewer import take_screenshot

        return take_screenshot
    raise AttributeError(name)
