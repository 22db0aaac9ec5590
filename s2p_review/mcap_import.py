"""MCAP import: restore a scene folder and its run from an ``s2p export`` file (the
attachments and the lossless /s2p/ channels, see ``mcap_export`` and ``mcap_records``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from s2p_review import mcap_records as R
from s2p_review.annotated_mcap import (
    PREFIX,
    SCENE_FILES,
    read_video,
    restore_annotation_files,
    restore_scene_files,
    restore_video,
)
from seg2pose.core.errors import InputError, S2PError
from seg2pose.core.validate import inside, safe_name
from seg2pose.io.atomic import os_errors, outputs, replacing
from seg2pose.io.nofollow import write_new_bytes
from seg2pose.io.run import write_run_folder
from seg2pose.io.scene import SCENE_FILE


@dataclass
class McapRecords:
    """The s2p content of an export: attachments (name -> bytes), metadata (name -> dict), and
    the /s2p/poses and /s2p/views messages in log-time order."""

    attachments: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    poses: list = field(default_factory=list)
    views: list = field(default_factory=list)


def read_mcap_records(path: Path) -> McapRecords:
    """Read the s2p content of an export; InputError when the file is missing, not MCAP, or
    not written by ``s2p export`` (no scene.json attachment)."""
    from mcap.reader import make_reader

    path = Path(path)
    if not path.exists():
        raise InputError("MCAP file not found", file=path)
    res = McapRecords()
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            for a in reader.iter_attachments():
                res.attachments[a.name] = a.data
            for m in reader.iter_metadata():
                res.metadata[m.name] = dict(m.metadata)
            for _schema, channel, msg in reader.iter_messages(topics=[R.POSES_TOPIC, R.VIEWS_TOPIC],
                                                              log_time_order=True):
                d = json.loads(msg.data)
                (res.poses if channel.topic == R.POSES_TOPIC else res.views).append(d)
    except Exception as e:  # noqa: BLE001 - mcap raises many kinds on a damaged file
        raise InputError(f"not a readable MCAP file ({type(e).__name__}: {e})", file=path) from None
    if SCENE_FILE not in res.attachments:
        raise InputError("no scene.json attachment: not an `s2p export` file", file=path)
    return res


_MALFORMED = (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError)


def _parsed(fn, messages: list, topic: str, path: Path, *args):
    """``fn(messages, *args)``; a malformed message becomes one InputError naming the file,
    the topic and the message (by its index and frame)."""
    try:
        return fn(messages, *args)
    except _MALFORMED as e:
        for i, m in enumerate(messages):
            try:
                fn([m], *args)
            except _MALFORMED as e1:
                frame = m.get("frame", "?") if isinstance(m, dict) else "?"
                raise InputError(f"malformed {topic} message {i} (frame {frame}): "
                                 f"{type(e1).__name__}: {e1}", file=path) from None
        raise InputError(f"malformed {topic} messages: {type(e).__name__}: {e}", file=path) from None


def _restored_run(run_dir: Path, poses, views, meta: dict, path: Path) -> None:
    """Write the restored run folder: its writer checks the tables and run.json against the
    schemas their readers use (``io.schemas``: inf, negative sizes, duplicate rows, ...), and
    what it refuses is refused here naming the MCAP file."""
    try:
        write_run_folder(run_dir, poses, views, meta)
    except InputError as e:
        name = Path(e.file).name if e.file else "run folder"
        where = f" ({e.field})" if e.field else f" (line {e.line})" if e.line else ""
        raise InputError(f"the restored {name} would be invalid{where}: {e.message}", file=path) from None


def _check_attachments(scene_d: dict, att: dict, gfile: str, out_dir: Path, path: Path) -> None:
    """The scene.json and ground points attachments checked against the schema their reader
    uses (``io/scene_schema.py``) before anything is written: a scene ``load_scene`` would
    refuse (a camera named '../x', fps -1, two ground points, ...) is refused naming the MCAP
    file."""
    from seg2pose.io.scene_schema import ground_points_from_text, scene_fields

    try:
        scene_fields(scene_d, out_dir, out_dir / SCENE_FILE)
        try:
            text = att[gfile].decode("utf-8")
        except UnicodeDecodeError:
            raise InputError("not UTF-8 text", file=out_dir / gfile) from None
        ground_points_from_text(text, file=out_dir / gfile)
    except InputError as e:
        where = Path(e.file).name if e.file else SCENE_FILE
        where += (f" line {e.line}" if e.line else "") + (f" field {e.field}" if e.field else "")
        raise InputError(f"the restored scene would be invalid ({where}): {e.message}", file=path) from None


def _restore(tmp: Path, att: dict, gfile: str, run_rel: Path, table, rec: McapRecords,
             meta: dict, path: Path, check_annotations, video: dict) -> None:
    """Write the restored scene into the new folder ``tmp``: scene.json, the ground points,
    the run folder ``run_rel``, an annotated set's masks and video (``annotated_mcap``) and
    the annotation journal (checked by ``check_annotations``)."""
    with os_errors(tmp):
        write_new_bytes(tmp / SCENE_FILE, att[SCENE_FILE])
        (tmp / gfile).parent.mkdir(parents=True, exist_ok=True)
        write_new_bytes(tmp / gfile, att[gfile])
    try:
        run_meta = json.loads(att["run.json"]) if "run.json" in att else {}
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"the run.json attachment is not JSON ({e})", file=path) from None
    if not isinstance(run_meta, dict):
        raise InputError("the run.json attachment is not a JSON object", file=path)
    if "scene" in run_meta:  # the restored layout: OUT/out/<run> in the scene folder OUT
        run_meta["scene"] = "../.."
    views = (_parsed(R.views_table, rec.views, R.VIEWS_TOPIC, path)
             if meta.get("has_views") == "true" or rec.views else None)
    _restored_run(tmp / run_rel, table, views, run_meta, path)
    restore_scene_files(att, tmp, path)
    if video:
        try:
            fps, start_ns = float(meta["fps"]), int(meta.get("start_ns") or 0)
        except (KeyError, ValueError):
            raise InputError("metadata s2p: fps and start_ns are needed to number the video",
                             file=path) from None
        restore_video(video, tmp, fps, start_ns, path)
    restored = restore_annotation_files(att, tmp, path)
    if restored and check_annotations is not None:
        # the command layer opens the restored project (s2p_review cannot import annotate)
        check_annotations(tmp, path)


def import_mcap(path: Path, out_dir: Path, force: bool = False,
                check_annotations: Callable[[Path, Path], None] | None = None) -> Path:
    """Restore an ``s2p export`` file as a scene folder: OUT/scene.json and the ground points
    (bytes as exported), OUT/out/<run>/run.json, poses.csv (the exact pose table) and
    views.csv, and an annotation journal when the export carries one (OUT/annotations/).
    Refuses a non-empty ``out_dir`` unless ``force``; a new folder is renamed into place
    whole, and into an existing one (``force``) those outputs are swapped in as one set
    (``atomic.outputs``: the journal folder replaced whole, the folder's other files kept).
    ``check_annotations(folder, path)``, when given, is called on the restored folder before
    anything is moved into place (it raises for a journal that does not open). Returns the
    run folder."""
    path, out_dir = Path(path), Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()) and not force:
        raise S2PError(f"{out_dir} exists and is not empty; pass --force to write into it")
    rec = read_mcap_records(path)
    meta = rec.metadata.get("s2p", {})
    att = rec.attachments
    try:
        scene_d = json.loads(att[SCENE_FILE])
    except json.JSONDecodeError as e:
        raise InputError(f"the scene.json attachment is not JSON: {e.msg}", file=path) from None
    if not isinstance(scene_d, dict):
        raise InputError("the scene.json attachment is not a JSON object", file=path)
    gfile = scene_d.get("ground_points", "ground_points.csv")
    # a crafted file could name '../x' or '/home/...' here: it must stay inside OUT
    inside(out_dir, gfile, file=path, field="scene.json attachment: ground_points",
           what="ground points file")
    if gfile not in att:
        raise InputError(f"no {gfile} attachment", file=path)
    if Path(gfile) == Path(SCENE_FILE):
        raise InputError(f"the ground points file cannot be named {SCENE_FILE}", file=path,
                         field="scene.json attachment: ground_points")
    run_name = safe_name(meta.get("run") or "run", file=path, field="metadata s2p.run",
                         what="run name")
    table = _parsed(R.pose_table, rec.poses, R.POSES_TOPIC, path,
                    meta.get("poses_with_size", "true") == "true")

    _check_attachments(scene_d, att, gfile, out_dir, path)
    journal = any(a.startswith(PREFIX) for a in att)
    video = read_video(path)
    run_rel = Path("out") / run_name
    if not out_dir.exists() or not any(out_dir.iterdir()):
        # a new scene folder: built beside it and renamed into place as a whole
        with replacing(out_dir, force=True) as tmp:
            _restore(tmp, att, gfile, run_rel, table, rec, meta, path, check_annotations, video)
        return out_dir / run_rel
    # into an existing folder (--force): what the import writes (scene.json, the ground points,
    # the run folder and the annotation journal) as one set of outputs, each locked and
    # checked first, all built in one partial folder and swapped in together; the folder's
    # other files stay
    finals = [out_dir / SCENE_FILE, out_dir / gfile, out_dir / run_rel]
    if journal:
        finals.append(out_dir / PREFIX.rstrip("/"))
    if any(a.startswith(f"{SCENE_FILES}masks/") for a in att):
        finals.append(out_dir / "masks")
    if video:
        finals.append(out_dir / "video")
    with outputs(finals, force=True) as files:
        tmp = files.file(out_dir / SCENE_FILE).parent
        _restore(tmp, att, gfile, run_rel, table, rec, meta, path, check_annotations, video)
        for final in finals[1:]:
            files.adopt(final, tmp / final.relative_to(out_dir))
    return out_dir / "out" / run_name
