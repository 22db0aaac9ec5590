"""Everything Rerun and MCAP: entity layout, blueprint, logging, viewer control, MCAP export
and import.

Modules (one concern each)::

    selection    runs, frame range, cameras and image cadence to show (shared)
    imagery      video frames and mask frames read from a scene (shared)
    timebase     frame numbers -> times (frame timeline, wall-clock time)
    layout       the entity tree, class colours, the blueprint
    columns      whole tracks and frame ranges as arrays for rr.send_columns
    recording    one log function per entity family
    session      ``record``: where a recording goes (file, viewers, screenshot)
    viewer       viewer control (spawn, connect, time cursor, screenshots)
    foxglove     Foxglove protobuf message builders
    mcap_records the lossless /s2p/ JSON channels and their inverse
    mcap_export  ``export_mcap``;  mcap_import: ``import_mcap``
    runs         run folders read for review

Public API (imports are lazy so that ``import s2p_review`` does not load rerun)::

    record(scene, runs, to, options=None) -> RecordResult
    export_mcap(scene, run_dir, out_path, options=None, force=False) -> ExportResult
    import_mcap(path, out_dir, force=False) -> Path
    take_screenshot(source, png_path, *, frame=None, force=False) -> Path
"""

from __future__ import annotations

import os

# Rerun logs a sink that cannot write in lines of its own beside s2p's one line naming the
# output (review -o writes the file itself: io/pipe_sink.py); read when rerun is first
# imported, which the modules here do: set before, unless the user has set RUST_LOG
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off")

__all__ = ["record", "RecordOptions", "Targets", "export_mcap", "ExportOptions", "import_mcap",
           "take_screenshot"]

_WHERE = {"record": "session", "RecordOptions": "session", "Targets": "session",
          "export_mcap": "mcap_export", "ExportOptions": "mcap_export",
          "import_mcap": "mcap_import", "take_screenshot": "viewer"}


def __getattr__(name: str):
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(f"s2p_review.{_WHERE[name]}"), name)
    raise AttributeError(name)
