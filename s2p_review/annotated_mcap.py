"""An annotated MCAP set: a scene with its annotated tracks in place of a run's road users (each
pose says whether it is a keyframe, interpolated or occluded: in the lossless /s2p/poses records
and in the Foxglove labels) and the annotation journal as attachments named
``annotations/<file>``. ``mcap_import`` writes those back into the restored scene folder, where
the annotation project opens again with its tracks and undo history.

The journal is passed in as bytes (the command layer reads it with ``annotate``): review code
does not depend on the annotation engine.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from s2p_review.mcap_export import ExportOptions, ExportResult, export_mcap
from seg2pose.core.validate import safe_name
from seg2pose.io.atomic import atomic_write_bytes
from seg2pose.io.scene import Scene

PREFIX = "annotations/"


def _file_name(attachment: str, file: str | Path | None = None) -> str | None:
    """The file name inside ``annotations/`` of an attachment name, or None if it is not one;
    a name that is not a plain file name (folders, '..', a leading dot) is an error."""
    if not attachment.startswith(PREFIX):
        return None
    return safe_name(attachment[len(PREFIX):], file=file, field=f"attachment {attachment}",
                     what="journal file name")


def export_annotated_mcap(scene: Scene, run_dir: Path, out_path: Path, journal: dict[str, bytes],
                          options: ExportOptions | None = None, force: bool = False) -> ExportResult:
    """``export_mcap`` of ``scene`` with the annotation run folder ``run_dir`` (annotated poses
    with their source column) plus ``journal`` (``annotations/<file>`` -> bytes) attached."""
    for name in journal:
        if _file_name(name) is None:
            raise ValueError(f"journal file {name!r} must be named {PREFIX}<file>")
    extra = dict((options.attachments or {}) if options else {})
    extra.update(journal)
    opts = dataclasses.replace(options or ExportOptions(), attachments=extra)
    return export_mcap(scene, run_dir, out_path, opts, force)


def restore_annotation_files(attachments: dict[str, bytes], folder: Path,
                             file: str | Path | None = None) -> list[Path]:
    """Write the ``annotations/<file>`` attachments into ``folder/annotations/``; returns the
    paths written. An attachment name that would leave that folder is an error naming it."""
    out = []
    for att, data in sorted(attachments.items()):
        name = _file_name(att, file)
        if name is None:
            continue
        path = Path(folder) / PREFIX.rstrip("/") / name
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)
        out.append(path)
    return out
