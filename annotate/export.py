"""Exports of an annotation project that close the loop: ground truth for training
(``gt/poses.csv`` with a ``source`` column), the journal files for an MCAP set, and a run-like
folder of the annotated poses that review tools (the MCAP exporter) read as they read a run.

    from annotate import Project
    from annotate.export import export_gt
    with Project.open("scene", read_only=True) as p:
        export_gt(p)            # scene/gt/poses.csv: every annotated frame, source column

Which rows: every frame from a track's first to its last keyframe, except frames in
``outside`` spans (and beyond the last keyframe before / first after such a span). source is
the row's provenance (table.py): ``keyframe``, ``estimate-accepted``, ``estimate-unchecked``,
``interpolated``, ``reviewed`` or ``occluded``. Unchecked estimates are refused unless asked
for (``gt_table``); training skips them and occluded rows.
"""

from __future__ import annotations

from pathlib import Path

from annotate import journal as J
from annotate.table import UNCHECKED, source_counts
from seg2pose.core.errors import S2PError
from seg2pose.io.poses import SOURCES, PoseTable, write_poses

RUN_META = {"kind": "annotations", "method": "annotation (keyframes + interpolation)"}


def annotated_poses(project, frames: tuple[int, int] | None = None) -> PoseTable:
    """The project's per-frame poses as a PoseTable with sizes and the source column, rows by
    frame then track id (the order of pose files)."""
    return project.poses(frames=frames)


def gt_replaceable(path: Path, force: bool) -> bool:
    """Whether ``path`` may be replaced by an annotation export: absent, from an earlier
    annotation export (it has a ``source`` column), or ``force``. Else an S2PError."""
    if force or not path.exists():
        return True
    try:
        with open(path, encoding="utf-8") as f:
            header = f.readline().strip().split(",")
    except (OSError, UnicodeDecodeError):
        header = []
    if header[-1:] != ["source"]:
        raise S2PError(f"{path} holds ground truth that is not an annotation export (no "
                       "source column); pass --force to replace it, or choose another output")
    return True


class UnreviewedError(S2PError):
    """An export refused because rows are unchecked estimates; ``counts``: {track: rows}."""

    def __init__(self, message: str, counts: dict[int, int]):
        super().__init__(message)
        self.counts = counts


def provenance_line(table: PoseTable) -> str:
    """Rows per provenance over all tracks, e.g. ``120 keyframe, 3400 interpolated``."""
    total: dict[str, int] = {}
    for c in source_counts(table).values():
        for k, n in c.items():
            total[k] = total.get(k, 0) + n
    return ", ".join(f"{total[k]} {k}" for k in SOURCES if k in total) or "no rows"


def gt_table(project, allow_unreviewed: bool = False) -> PoseTable:
    """The annotated poses for ``gt/poses.csv``. An S2PError when there are none; an
    ``UnreviewedError`` when rows are unchecked estimates (source ``estimate-unchecked``: a
    pre-annotation or estimates taken every N frames that nobody has reviewed) unless
    ``allow_unreviewed``, with which they are written, their source saying so."""
    table = annotated_poses(project)
    if not len(table):
        raise S2PError(f"{project.scene.root}: the annotation project has no annotated poses yet")
    if not allow_unreviewed:
        counts = {t: c[UNCHECKED] for t, c in source_counts(table).items() if UNCHECKED in c}
        if counts:
            worst = sorted(counts.items(), key=lambda kv: -kv[1])[:8]
            raise UnreviewedError(
                f"{sum(counts.values())} rows of {len(counts)} tracks are unchecked estimates "
                f"(neither keyframed nor reviewed; tracks {', '.join(f'{t}: {n}' for t, n in worst)}"
                f"{', ...' if len(counts) > len(worst) else ''}): review them, or export them "
                "marked estimate-unchecked", counts)
    return table


def export_gt(project, path: str | Path | None = None, force: bool = False) -> Path:
    """Write the annotated poses to ``path`` (default: the scene's ``gt/poses.csv``), atomically.

    An existing file that came from an annotation export (it has a ``source`` column) is
    replaced; ground truth from elsewhere (no ``source`` column) is kept unless ``force``."""
    from seg2pose.io.atomic import replacing

    path = Path(path) if path is not None else project.scene.gt_path
    with replacing(path, force=gt_replaceable(path, force), folder=False) as tmp:
        write_poses(tmp, gt_table(project))
    return path


def journal_files(project) -> dict[str, bytes]:
    """The journal as files to carry in an export: relative name (``annotations/...``) -> bytes
    (``Project.journal_files``: snapshot and segments, no lock). Restored into a copy of the
    scene folder, ``Project.open`` there gives the same tracks and history."""
    out = {f"{J.ANNOTATIONS}/{p.name}": p.read_bytes() for p in project.journal_files()}
    if not out:
        raise S2PError(f"{project.folder}: no journal yet (nothing annotated)")
    return out


def write_annotation_run(project, folder: str | Path, force: bool = False) -> Path:
    """A run folder of the annotated poses (``poses.csv`` with the source column, ``run.json``
    saying it holds annotations), for tools that read runs (review, MCAP export)."""
    from seg2pose.io.run import relative_path, write_run_folder

    folder = Path(folder)
    meta = dict(RUN_META, scene=relative_path(project.scene.root, folder),
                scene_fingerprint=project.fingerprint, journal_records=project.seq)
    return write_run_folder(folder, annotated_poses(project), None, meta, force=force)
