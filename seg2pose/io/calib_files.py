"""The files of a camera calibration from clicked points: point pairs, surveyed points, aerial
images' georeference (world files, two reference points), and the written result.

pairs.csv: ``camera,u,v,x,y,z[,name]`` per line (a header line optional): pixel (u, v) in the
camera's frame (corner-origin, camera.py) and its world point (metres, z up; z empty when the
elevation is not known).

survey.csv: ``name,x,y,z`` per line (z may be empty).

World file (``.pgw``, ``.jgw``, ``.tfw``, ``.wld``; ESRI's format): six numbers, one a line,
A D B E C F, so that the centre of pixel (col, row) (0-based indices) lies at
x = A col + B row + C, y = D col + E row + F (E < 0 for north-up images). In s2p's corner
convention the centre of pixel index col is at u = col + 0.5, so x = A (u - 0.5) + B (v - 0.5) + C.

Two reference points: two pixels of the aerial image with their world x, y: a similarity
(scale, rotation, translation) with the image's y axis pointing down, world y up.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import MAX_COORD, MAX_PIXEL_COORD, safe_name
from seg2pose.geometry.camera import Camera
from seg2pose.io.atomic import atomic_write_bytes, atomic_write_text, outputs
from seg2pose.io.schema import check
from seg2pose.io.schemas import CALIB_FILE
from seg2pose.io.text import load_json, read_text

WORLD_FILE_EXTS = (".pgw", ".jgw", ".tfw", ".wld", ".pngw", ".jpgw")


def _rows(path: Path, what: str):
    text = read_text(path, what)
    reader = csv.reader(io.StringIO(text))
    try:
        for row in reader:
            if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#"):
                yield reader.line_num, [c.strip() for c in row]
    except csv.Error as e:
        raise InputError(f"malformed CSV: {e}", file=path, line=reader.line_num) from None


def _num(text: str, path: Path, line: int, field: str, lim: float, empty_ok: bool = False) -> float:
    if text == "" and empty_ok:
        return float("nan")
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"expected a number, got {text!r}", file=path, line=line, field=field) from None
    if not np.isfinite(v) or abs(v) > lim:
        raise InputError(f"expected a finite number within +-{lim:g}, got {text!r}", file=path,
                         line=line, field=field)
    return v


def read_pairs(path: str | Path) -> dict[str, dict]:
    """Camera -> {"uv": (N, 2), "X": (N, 3) (z NaN when unknown), "names": [...]} from a
    pairs CSV (module doc). Names default to ``line N``."""
    path = Path(path)
    out: dict[str, dict] = {}
    cols = ["camera", "u", "v", "x", "y", "z", "name"]
    first = True
    for line, row in _rows(path, "pairs file"):
        if first and row[0].lower() == "camera":
            cols = [c.lower() for c in row]
            missing = [c for c in ("camera", "u", "v", "x", "y", "z") if c not in cols]
            if missing:
                raise InputError(f"the header lacks {missing}; expected camera,u,v,x,y,z[,name]",
                                 file=path, line=line)
            first = False
            continue
        first = False
        if len(row) < 6 or len(row) > len(cols):
            raise InputError(f"expected fields camera,u,v,x,y,z[,name], got {len(row)}", file=path,
                             line=line)
        rec = dict(zip(cols, row, strict=False))
        cam = safe_name(rec["camera"], file=path, field=f"line {line} camera", what="camera name")
        uv = [_num(rec[k], path, line, k, MAX_PIXEL_COORD) for k in ("u", "v")]
        X = [_num(rec[k], path, line, k, MAX_COORD, empty_ok=(k == "z")) for k in ("x", "y", "z")]
        d = out.setdefault(cam, {"uv": [], "X": [], "names": []})
        d["uv"].append(uv)
        d["X"].append(X)
        d["names"].append(rec.get("name") or f"line {line}")
    if not out:
        raise InputError("no pairs (expected lines camera,u,v,x,y,z)", file=path)
    return {c: {"uv": np.array(d["uv"], float), "X": np.array(d["X"], float), "names": d["names"]}
            for c, d in out.items()}


def read_survey(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Names and points (n, 3) metres (z NaN when empty) of a survey CSV ``name,x,y,z``."""
    path = Path(path)
    names: list[str] = []
    pts: list[list[float]] = []
    for line, row in _rows(path, "survey file"):
        if not pts and row[0].lower() == "name":
            continue
        if len(row) not in (3, 4):
            raise InputError(f"expected name,x,y,z, got {len(row)} fields", file=path, line=line)
        row = row + [""] * (4 - len(row))
        if row[0] in names:
            raise InputError(f"duplicate point name {row[0]!r}", file=path, line=line)
        names.append(row[0] or f"line {line}")
        pts.append([_num(row[1], path, line, "x", MAX_COORD), _num(row[2], path, line, "y", MAX_COORD),
                    _num(row[3], path, line, "z", MAX_COORD, empty_ok=True)])
    if not pts:
        raise InputError("no surveyed points (expected lines name,x,y,z)", file=path)
    return names, np.array(pts, float)


# --- aerial georeference -----------------------------------------------------------------------------
def read_world_file(path: str | Path) -> np.ndarray:
    """The (2, 3) affine map A with world xy = A @ [u, v, 1] (s2p's pixel corner convention)
    from a world file (module doc)."""
    path = Path(path)
    text = read_text(path, "world file")
    lines = [s.strip() for s in text.splitlines() if s.strip()]
    want = "a world file holds six numbers, one a line (A D B E C F)"
    if len(lines) != 6:
        raise InputError(f"{want}; this one has {len(lines)} lines", file=path)
    vals = []
    for i, s in enumerate(lines):
        try:
            v = float(s)
        except ValueError:
            raise InputError(f"{want}; got {s[:40]!r}", file=path, line=i + 1) from None
        if not np.isfinite(v) or abs(v) > MAX_COORD * 10:
            raise InputError(f"{want}; got {s[:40]!r}", file=path, line=i + 1)
        vals.append(v)
    a, d, b, e, c, f = vals
    if abs(a * e - b * d) < 1e-18 or max(abs(a), abs(b), abs(d), abs(e)) > 1e4:
        raise InputError(f"the pixel size terms (A={a:g}, D={d:g}, B={b:g}, E={e:g}) map the image to "
                         "a line or a point, or a pixel larger than 10 km; not a usable world file", file=path)
    # centre of pixel index (col, row) = (u - 0.5, v - 0.5)
    return np.array([[a, b, c - 0.5 * (a + b)], [d, e, f - 0.5 * (d + e)]])


def two_point_georeference(px: np.ndarray, world: np.ndarray) -> np.ndarray:
    """The (2, 3) similarity map (image y down, world y up) through two reference points:
    px (2, 2) pixels, world (2, 2) metres. With complex numbers p = u - i v (y flipped) and
    w = x + i y, w = a p + b: two points give a and b."""
    px, world = np.asarray(px, float).reshape(2, 2), np.asarray(world, float).reshape(2, 2)
    p = px[:, 0] - 1j * px[:, 1]
    w = world[:, 0] + 1j * world[:, 1]
    if abs(p[1] - p[0]) < 1.0:
        raise InputError("the two reference pixels are less than a pixel apart", field="reference")
    if abs(w[1] - w[0]) < 1e-3:
        raise InputError("the two reference points' world positions coincide", field="reference")
    a = (w[1] - w[0]) / (p[1] - p[0])
    b = w[0] - a * p[0]
    # x + i y = (ar + i ai)(u - i v) + b
    return np.array([[a.real, a.imag, b.real], [a.imag, -a.real, b.imag]])


def aerial_to_world(A: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Aerial pixels (N, 2) -> world xy (N, 2) with the affine map A (2, 3)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    return uv @ A[:, :2].T + A[:, 2]


def world_to_aerial(A: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """World xy (N, 2) -> aerial pixels (N, 2)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    return np.linalg.solve(A[:, :2], (xy - A[:, 2]).T).T


def write_world_file(path: str | Path, A: np.ndarray) -> None:
    """Write the affine map A (2, 3) as a world file (inverse of ``read_world_file``)."""
    a, b = A[0, 0], A[0, 1]
    d, e = A[1, 0], A[1, 1]
    c = A[0, 2] + 0.5 * (a + b)
    f = A[1, 2] + 0.5 * (d + e)
    atomic_write_text(path, "".join(f"{v!r}\n" for v in (float(a), float(d), float(b), float(e),
                                                          float(c), float(f))))


# --- the result ------------------------------------------------------------------------------------------
def output_names(out: Path, cameras: list[str]) -> dict[str, Path]:
    """The files written beside calib.json: ``<stem>.ground.csv``, ``<stem>.report.txt`` and one
    ``<stem>.<camera>.png`` per camera."""
    out = Path(out)
    names = {"calib": out, "ground": out.with_name(f"{out.stem}.ground.csv"),
             "report": out.with_name(f"{out.stem}.report.txt")}
    for c in cameras:
        names[f"png:{c}"] = out.with_name(f"{out.stem}.{c}.png")
    return names


def calib_json(cameras: list[dict], report: dict, file: str | Path | None = None) -> str:
    """calib.json's text: ``{"cameras": [...], "report": {...}}`` (what ``s2p new-scene``
    reads: the cameras; the report rides along). The cameras are read back as
    ``read_calib_json`` reads them (a degenerate solve's NaN, a bad name: one line naming
    ``file``, nothing written); the report's non-finite numbers are written as null
    (unknown: JSON has no NaN)."""
    d = {"cameras": cameras, "report": _finite_or_null(report)}
    calib_cameras(d, file=file)
    return json.dumps(d, indent=1, allow_nan=False) + "\n"


def _finite_or_null(v):
    if isinstance(v, float) and not np.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _finite_or_null(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite_or_null(x) for x in v]
    if isinstance(v, np.generic):
        return _finite_or_null(v.item())
    return v


def calib_cameras(d, file: str | Path | None = None, sizes: dict[str, tuple[int, int]] | None = None
                  ) -> dict[str, Camera]:
    """The cameras of calib.json's object ``d`` (``io.schemas.CALIB_FILE``: ``{"cameras":
    [...]}`` or one camera object), each as scene.json holds a camera (``Camera.from_dict``),
    names unique. ``sizes``: camera name -> (width, height) for cameras without an image size
    (a video's); a camera without one and without a video of its name is left out."""
    sizes = sizes or {}
    items = d.get("cameras") if isinstance(d, dict) and "cameras" in d else [d]
    if not isinstance(items, list) or not items:
        raise InputError("expected {\"cameras\": [...]} or one camera object", file=file)
    if isinstance(d, dict) and "cameras" in d:
        check(d, CALIB_FILE, file=file)
    cams: dict[str, Camera] = {}
    for i, c in enumerate(items):
        if not isinstance(c, dict):
            raise InputError("expected an object", file=file, field=f"cameras[{i}]")
        c = dict(c)
        if "name" not in c and len(items) == 1 and len(sizes) == 1:
            c["name"] = next(iter(sizes))
        if ("width" not in c or "height" not in c) and sizes:
            if str(c.get("name")) not in sizes:  # no video of that name to take the size from
                continue
            c["width"], c["height"] = sizes[str(c.get("name"))]
        cam = Camera.from_dict(c, file=file, where=f"cameras[{i}]")
        if cam.name in cams:
            raise InputError(f"duplicate camera name {cam.name!r}", file=file, field=f"cameras[{i}].name")
        cams[cam.name] = cam
    return cams


def read_calib_json(path: str | Path, sizes: dict[str, tuple[int, int]] | None = None
                    ) -> tuple[dict[str, Camera], list[str]]:
    """The cameras of a calib.json file (``calib_cameras``) and the names of those left out for
    want of an image size."""
    path = Path(path)
    d = load_json(path, "calibration file")
    cams = calib_cameras(d, file=path, sizes=sizes)
    items = d.get("cameras") if isinstance(d, dict) and "cameras" in d else [d]
    unsized = [str(c.get("name")) for c in items or [] if isinstance(c, dict)
               and str(c.get("name")) not in cams and ("width" not in c or "height" not in c)]
    return cams, unsized


def write_calibration(out: str | Path, cameras: list[dict], report: dict, report_text: str,
                      ground: np.ndarray, pictures: dict[str, bytes], force: bool = False
                      ) -> dict[str, Path]:
    """calib.json and the files beside it (``output_names``), locked, refused when present
    unless ``force``, built beside and swapped in as a set."""
    from seg2pose.io.scene_schema import ground_points_text

    names = output_names(Path(out), list(pictures))
    text = calib_json(cameras, report, file=names["calib"])
    # checked as s2p new-scene --ground reads them, before anything is written
    ground_text = ground_points_text(ground, file=names["ground"])
    with outputs(list(names.values()), force) as files:
        atomic_write_text(files.file(names["calib"]), text)
        atomic_write_text(files.file(names["ground"]), ground_text)
        atomic_write_text(files.file(names["report"]), report_text)
        for c, png in pictures.items():
            atomic_write_bytes(files.file(names[f"png:{c}"]), png)
    return names


CALIBRATIONS = "calibrations"  # a scene's calibration versions: calibrations/v<N>/


def next_version(root: Path) -> int:
    """The number of a scene's next calibration version (1 when it has none)."""
    folder = Path(root) / CALIBRATIONS
    nums = [int(p.name[1:]) for p in folder.glob("v*") if p.name[1:].isdigit()] if folder.is_dir() else []
    return max(nums, default=0) + 1


def write_scene_version(root: str | Path, new_scene_json: str, old_scene_json: str,
                        files: dict[str, bytes], version: int) -> Path:
    """A scene's new calibration version: ``calibrations/v<N>/`` with the scene.json it
    replaces (``scene-before.json``) and ``files`` (name -> bytes: calib.json, report,
    pictures), and the new scene.json, swapped in together under their locks. The version
    folder must be new (a version is never overwritten). The new scene.json is checked first
    against the schema its reader uses (``io/scene_schema.py``): nothing is written when
    ``load_scene`` would refuse it."""
    from seg2pose.io.scene_schema import SCENE_FILE, writable_scene

    root = Path(root)
    vdir = root / CALIBRATIONS / f"v{version}"
    scene_path = root / SCENE_FILE
    try:
        new = json.loads(new_scene_json)
    except json.JSONDecodeError as e:
        raise InputError(f"the new scene.json is not JSON: {e.msg}", file=scene_path) from None
    writable_scene(new, root, scene_path)
    with outputs([vdir], force=False, records=[scene_path]) as out:
        tmp = out.folder(vdir)
        atomic_write_text(tmp / "scene-before.json", old_scene_json)
        for name, data in files.items():
            atomic_write_bytes(tmp / name, data)
        atomic_write_text(out.file(scene_path), new_scene_json)
    return vdir


def write_result(res, text: str, pictures: dict[str, bytes], out: Path | None, scene=None,
                 force: bool = False) -> list[str]:
    """A solved site (geometry.calib_site.SiteResult) written where the user asked: calib.json
    and the files beside it at ``out``, else into ``scene`` (io.scene.Scene) as its next
    calibration version, which needs ``force`` (never a silent change of a scene's cameras)
    and pairs for each of its cameras. Returns lines that say what was written."""
    if out is not None or scene is None:
        if out is None:
            raise InputError("give -o calib.json (or a scene folder to write a new version into)", field="out")
        names = write_calibration(out, res.camera_dicts(), res.report(), text, res.ground.points,
                                  pictures, force)
        return [f"written: {names['calib']} (s2p new-scene --calibration {names['calib']} --ground "
                f"{names['ground']}), {names['report'].name}, "
                + ", ".join(names[k].name for k in names if k.startswith("png:"))]
    from seg2pose.geometry.camera import Rig
    from seg2pose.io.scene import SCENE_FILE

    missing = [c for c in scene.cameras if c not in res.cameras]
    if missing:
        raise InputError(f"the pairs calibrate {sorted(res.cameras)} but the scene also has "
                         f"{missing}; give pairs for every camera", file=scene.root / SCENE_FILE)
    if not force:
        raise InputError("the scene has cameras already; --force replaces them as the scene's next "
                         "calibration version (the old scene.json is kept in calibrations/vN/)",
                         file=scene.root / SCENE_FILE)
    old_text = read_text(scene.root / SCENE_FILE, "scene file")
    version = next_version(scene.root)
    cams = {c: res.cameras[c].solution.camera for c in scene.cameras}
    lines = []
    for c, cam in cams.items():
        old = scene.cameras[c]
        lines.append(f"camera {c}: focal {old.K[0, 0]:.1f} -> {cam.K[0, 0]:.1f} px, centre moved "
                     f"{np.linalg.norm(cam.center - old.center):.2f} m")
    scene.rig = Rig(cameras=cams, configs=scene.rig.configs, name=scene.rig.name)
    history = list((scene.extra.get("calibration") or {}).get("history", []))
    history.append(f"{CALIBRATIONS}/v{version}")
    scene.extra["calibration"] = {"version": version, "history": history, "ground": res.ground.summary}
    files = {"calib.json": calib_json(res.camera_dicts(), res.report()).encode(),
             "report.txt": text.encode(), **{f"{c}.png": b for c, b in pictures.items()}}
    vdir = write_scene_version(scene.root, json.dumps(scene.to_dict(), indent=1) + "\n", old_text,
                               files, version)
    lines.append(f"scene {scene.root}: cameras replaced as calibration version {version} ({vdir}); the "
                 "scene's ground points are kept (the clicked elevations' ground is in the report)")
    return lines
