"""How a scene's track ids were made: ``masks/ids.json``, one entry per camera's masks file.

Late fusion joins the views of several cameras by track id, which is right only when one road
user has one id in every camera: ids from ground truth (a synthetic scene, an annotation, a
dataset) or from ``s2p associate``. Each camera's own tracker numbers its tracks 1, 2, 3 ...
regardless of the other cameras. So every writer of track ids says here what it made:

```
{"version": 1,
 "cameras": {"c0": {"ids": "tracker" | "associated" | "truth",
                    "with": ["c0", "c1", ...],     # associated: the cameras joined
                    "sha256": "...",               # of masks/c0.txt as written
                    "made": "2026-12-02T05:00:00+00:00"}}}
```

The digest ties an entry to the file: masks rewritten later (by hand, another tool) no longer
match it and their ids count as unknown. A scene without the file (every scene made before it
existed: synthetic scenes, imports of datasets with ground truth) has ids "given": they are
fused as before, except in a scene made from video by ``s2p new-scene``, whose masks can only
have come from a per-camera tracker.
"""

from __future__ import annotations

import json
from pathlib import Path

from seg2pose.core.clock import utc_now
from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import OutputSet, atomic_write_text, output_lock
from seg2pose.io.nofollow import write_new_text

IDS_FILE = "ids.json"
KINDS = ("tracker", "associated", "truth")


def ids_path(masks_dir: str | Path) -> Path:
    return Path(masks_dir) / IDS_FILE


def read_ids(masks_dir: str | Path) -> dict[str, dict]:
    """camera -> its entry (see the module docstring); {} without the file."""
    p = ids_path(masks_dir)
    if not p.exists():
        return {}
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"not valid JSON ({e})", file=p) from None
    cams = d.get("cameras") if isinstance(d, dict) else None
    if not isinstance(cams, dict) or not all(isinstance(v, dict) for v in cams.values()):
        raise InputError('expected {"version": 1, "cameras": {camera: {"ids": ...}}}', file=p)
    for c, v in cams.items():
        if v.get("ids") not in KINDS:
            raise InputError(f"expected one of {', '.join(KINDS)}, got {v.get('ids')!r}", file=p,
                             field=f"cameras.{c}.ids")
    return cams


def entries(masks_dir: str | Path, kinds: dict[str, str], with_cameras: list[str] | None = None,
            built: dict[str, Path] | None = None) -> dict[str, dict]:
    """New entries for the written masks files ``masks_dir/<camera>.txt`` (or, for a camera
    in ``built``, the file built to replace it): camera -> kind."""
    made = utc_now()
    out = {}
    for c, kind in kinds.items():
        if kind not in KINDS:
            raise ValueError(f"unknown kind of ids {kind!r}")
        f = (built or {}).get(c) or Path(masks_dir) / f"{c}.txt"
        e: dict[str, str | list[str]] = {"ids": kind, "sha256": file_sha256(f), "made": made}
        if kind == "associated":
            e["with"] = list(with_cameras or kinds)
        out[c] = e
    return out


def ids_text(cams: dict[str, dict]) -> str:
    return json.dumps({"version": 1, "cameras": dict(sorted(cams.items()))}, indent=1) + "\n"


def stage_ids(files: OutputSet, masks_dir: str | Path, kinds: dict[str, str],
              built: dict[str, Path], with_cameras: list[str] | None = None) -> None:
    """Build the new ``masks/ids.json`` in the output set ``files`` (which holds it and the
    masks ``built``: camera -> where its new masks file is built): the masks and the record of
    how their ids were made are swapped in together (``atomic.outputs(..., records=[ids])``),
    so that no kill leaves one camera's new tracker ids beside a record (or no record) that
    calls them something else. Other cameras' entries stay."""
    p = ids_path(masks_dir)
    cams = read_ids(masks_dir)
    cams.update(entries(masks_dir, kinds, with_cameras, built))
    write_new_text(files.file(p), ids_text(cams))


def mark_ids(masks_dir: str | Path, kinds: dict[str, str], with_cameras: list[str] | None = None
             ) -> None:
    """Record how the ids of ``masks_dir/<camera>.txt`` were made (camera -> kind); other
    cameras' entries stay. Under the file's lock, written atomically."""
    p = ids_path(masks_dir)
    with output_lock(p):
        cams = read_ids(masks_dir)
        cams.update(entries(masks_dir, kinds, with_cameras))
        atomic_write_text(p, ids_text(cams))


def ids_status(masks_dir: str | Path, cameras: list[str], from_video: bool = False
               ) -> tuple[str, str]:
    """How the ids of ``cameras`` were made, for fusing them: ("associated" | "truth" |
    "given" | "unassociated", why). "unassociated": some camera's ids are a tracker's, or its
    masks changed after association, or it was associated without the others."""
    cams = read_ids(masks_dir)
    if not cams:
        if from_video and len(cameras) > 1:
            return "unassociated", ("the scene was made from video and its masks carry no "
                                    f"record of association ({Path(masks_dir) / IDS_FILE})")
        return "given", f"no {IDS_FILE}: ids taken as given (ground truth or another tool's)"
    kinds = set()
    for c in cameras:
        e = cams.get(c)
        f = Path(masks_dir) / f"{c}.txt"
        if e is None:
            return "unassociated", f"{IDS_FILE} has no entry for camera {c}"
        if not f.exists() or e.get("sha256") != file_sha256(f):
            return "unassociated", f"{f} changed after its ids were recorded ({e['ids']})"
        if e["ids"] == "tracker" and len(cameras) > 1:
            return "unassociated", f"camera {c}'s ids are its own tracker's"
        if e["ids"] == "associated" and len(cameras) > 1 and not set(cameras) <= set(e.get("with", [])):
            return "unassociated", (f"camera {c} was associated with {e.get('with')} only, "
                                    f"not with all of {cameras}")
        kinds.add(e["ids"])
    kind = "associated" if "associated" in kinds else ("truth" if kinds == {"truth"} else "given")
    return kind, f"{IDS_FILE}: " + ", ".join(f"{c} {cams[c]['ids']}" for c in cameras)
