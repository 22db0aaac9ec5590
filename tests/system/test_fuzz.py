"""Fuzzing of every reader, in one place (hypothesis): near-valid inputs (a valid file with one
field mutated, truncated, swapped or made absurd) and random bytes must end in the project's
own error (S2PError) or parse; valid inputs must parse to exactly the values written."""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from hostile_fixtures import H, W, write_s2p_mcap, write_scene, write_utocs
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from io_fixtures import RLE, make_scene, same_masks
from io_fixtures import H as IO_H
from io_fixtures import W as IO_W

from seg2pose.core.errors import S2PError
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.png import read_png_folder, write_png_folder
from seg2pose.io.poses import PoseTable, read_poses, write_poses
from seg2pose.io.scene import load_scene, read_ground_points, write_ground_points
from seg2pose.structures.masks import decode, encode

FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

HOSTILE_JSON = [None, True, False, 0, -1, 1.9, 2.0, -5.5, 1e308, -1e308, 10 ** 30, 2 ** 63,
                math.inf, -math.inf, math.nan, "", "x", "1", "../x", "/etc/passwd", "a/b", [], {},
                [1, 2], [[0, 0, 0]] * 3, {"a": 1}]
HOSTILE_TEXT = ["", "-1", "1_4", "\u0661", "1e400", "nan", "inf", "-inf", "true", "1.5", "0x10",
                "9" * 25, " ", "a,b", '"', "\x00", "\u00e9", "-0", "+3", "1e308", "../x"]


@contextlib.contextmanager
def folder():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


def only_s2p_errors(fn):
    """Run fn(); return its result, or None when it raised S2PError (anything else fails)."""
    try:
        return fn()
    except S2PError:
        return None


# --- mutations ------------------------------------------------------------------------------------

def json_paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from json_paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from json_paths(v, prefix + (i,))


def mutate_json(data, obj):
    """One field of ``obj`` replaced by a hostile value or removed, two fields swapped, or
    the text truncated. Returns the new file text."""
    kind = data.draw(st.sampled_from(["replace", "delete", "swap", "truncate"]))
    text = json.dumps(obj)
    if kind == "truncate":
        return text[:data.draw(st.integers(0, max(0, len(text) - 1)))]
    paths = [p for p in json_paths(obj) if p]
    obj = json.loads(text)  # a copy
    p = data.draw(st.sampled_from(paths))
    parent = obj
    for k in p[:-1]:
        parent = parent[k]
    if kind == "replace":
        parent[p[-1]] = data.draw(st.sampled_from(HOSTILE_JSON))
    elif kind == "delete":
        del parent[p[-1]]
    else:
        q = data.draw(st.sampled_from(paths))
        qparent = obj
        try:
            for k in q[:-1]:
                qparent = qparent[k]
            parent[p[-1]], qparent[q[-1]] = qparent[q[-1]], parent[p[-1]]
        except (KeyError, IndexError, TypeError):
            pass  # the first change moved the second path
    return json.dumps(obj)


def mutate_text(data, text: str, sep: str | None) -> str:
    """One token replaced by a hostile one, a line removed, duplicated or swapped, or the
    text truncated."""
    kind = data.draw(st.sampled_from(["token", "token", "drop", "dup", "swap", "truncate"]))
    lines = text.splitlines()
    if kind == "truncate" or not lines:
        return text[:data.draw(st.integers(0, max(0, len(text) - 1)))]
    i = data.draw(st.integers(0, len(lines) - 1))
    if kind == "token":
        toks = lines[i].split(sep)
        j = data.draw(st.integers(0, len(toks) - 1))
        toks[j] = data.draw(st.sampled_from(HOSTILE_TEXT))
        lines[i] = (sep or " ").join(toks)
    elif kind == "drop":
        del lines[i]
    elif kind == "dup":
        lines.insert(i, lines[i])
    else:
        j = data.draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    return "\n".join(lines) + "\n"


# --- scene.json and ground points --------------------------------------------------------------

@FUZZ
@given(st.data())
def test_scene_json_near_valid(data):
    with folder() as d:
        write_scene(d, frames=1, users=1)
        obj = json.loads((d / "scene.json").read_text())
        (d / "scene.json").write_text(mutate_json(data, obj))
        s = only_s2p_errors(lambda: load_scene(d))
        if s is not None:  # what is accepted is sane
            assert FPS_OK(s.fps)
            for c in s.cameras.values():
                assert type(c.width) is int and 0 < c.width <= 2 ** 20
                assert np.isfinite(c.K).all() and np.allclose(c.K[2], [0, 0, 1])
            assert all(type(c.id) is int for c in s.classes)


def FPS_OK(fps: float) -> bool:
    return math.isfinite(fps) and 1e-3 <= fps <= 1e6


@FUZZ
@given(st.binary(max_size=400))
def test_scene_json_random_bytes(blob):
    with folder() as d:
        write_scene(d, frames=1, users=1)
        (d / "scene.json").write_bytes(blob)
        only_s2p_errors(lambda: load_scene(d))


finite = st.floats(-1e5, 1e5, allow_nan=False, allow_subnormal=True)


@FUZZ
@given(st.lists(st.tuples(finite, finite, finite), min_size=3, max_size=30, unique=True))
def test_ground_points_round_trip(pts):
    with folder() as d:
        write_ground_points(d / "g.csv", np.array(pts))
        assert np.array_equal(read_ground_points(d / "g.csv"), np.array(pts))


@FUZZ
@given(st.data())
def test_ground_points_near_valid(data):
    with folder() as d:
        write_ground_points(d / "g.csv", np.array([[0.0, 0, 0], [1, 0, 0.5], [0, 2, 1], [3, 3, -1]]))
        (d / "g.csv").write_text(mutate_text(data, (d / "g.csv").read_text(), ","))
        pts = only_s2p_errors(lambda: read_ground_points(d / "g.csv"))
        if pts is not None:
            assert pts.shape[1] == 3 and len(pts) >= 3 and np.isfinite(pts).all()
            assert np.abs(pts).max() <= 1e6


# --- masks: MOTS, COCO, PNG ------------------------------------------------------------------------

@st.composite
def mask_tables(draw):
    """Non-overlapping box masks, one per (frame, track), frames in order."""
    n_frames = draw(st.integers(1, 4))
    fr, tid, cid, rles = [], [], [], []
    for f in sorted(draw(st.lists(st.integers(0, 10 ** 6), min_size=n_frames, max_size=n_frames,
                                  unique=True))):
        for k in range(draw(st.integers(1, 3))):
            m = np.zeros((H, W), np.uint8)
            x0 = 20 * k + draw(st.integers(0, 8))
            y0 = draw(st.integers(0, H - 2))
            m[y0:y0 + draw(st.integers(1, 10)), x0:x0 + draw(st.integers(1, 10))] = 1
            fr.append(f)
            tid.append(10 * k + draw(st.integers(0, 9)))  # unique within the frame
            cid.append(draw(st.integers(1, 3)))
            rles.append(encode(m))
    return MaskTable(fr, tid, cid, H, W, rles)


def same_table(a: MaskTable, b: MaskTable) -> bool:
    if len(a) != len(b) or (a.height, a.width) != (b.height, b.width):
        return False
    if not (np.array_equal(a.frame, b.frame) and np.array_equal(a.track_id, b.track_id)
            and np.array_equal(a.class_id, b.class_id)):
        return False
    return all(np.array_equal(decode(x, a.height, a.width), decode(y, b.height, b.width))
               for x, y in zip(a.rles, b.rles))


@FUZZ
@given(mask_tables())
def test_mots_and_coco_round_trip(t):
    with folder() as d:
        write_mots(d / "m.txt", t)
        assert same_table(read_mots(d / "m.txt"), t)
        write_coco(d / "m.json", t)
        assert same_table(read_coco(d / "m.json"), t)


@FUZZ
@given(mask_tables())
def test_png_round_trip(t):
    with folder() as d:
        write_png_folder(d / "png", t)
        r = read_png_folder(d / "png")
        order = np.lexsort((t.class_id * 1000 + t.track_id, t.frame))  # a frame's ids in order
        assert same_table(r, t.take(order))


def _valid_masks(d: Path) -> MaskTable:
    return read_mots(write_scene(d, frames=3, users=2).masks_path("c0"))


@FUZZ
@given(st.data())
def test_mots_near_valid(data):
    with folder() as d:
        t = _valid_masks(d)
        p = d / "m.txt"
        write_mots(p, t)
        p.write_text(mutate_text(data, p.read_text(), None))
        r = only_s2p_errors(lambda: read_mots(p, known_classes=[1, 2, 3]))
        if r is not None and len(r):
            assert (np.diff(r.frame) >= 0).all() and (r.frame >= 0).all()
            tracked = r.track_id >= 0
            keys = set(zip(r.frame[tracked].tolist(), r.track_id[tracked].tolist()))
            assert len(keys) == int(tracked.sum())


@FUZZ
@given(st.data())
def test_coco_near_valid(data):
    with folder() as d:
        t = _valid_masks(d)
        write_coco(d / "m.json", t)
        obj = json.loads((d / "m.json").read_text())
        (d / "m.json").write_text(mutate_json(data, obj))
        r = only_s2p_errors(lambda: read_coco(d / "m.json"))
        if r is not None and len(r):
            assert (r.frame >= 0).all() and r.height > 0 and r.width > 0


@FUZZ
@given(st.data())
def test_png_near_valid(data):
    import cv2

    with folder() as d:
        t = _valid_masks(d)
        paths = write_png_folder(d / "png", t)
        p = data.draw(st.sampled_from(paths))
        kind = data.draw(st.sampled_from(["truncate", "flip", "rgb", "float", "size", "bytes"]))
        raw = p.read_bytes()
        if kind == "truncate":
            p.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1))])
        elif kind == "flip":
            i = data.draw(st.integers(0, len(raw) - 1))
            p.write_bytes(raw[:i] + bytes([raw[i] ^ 0xFF]) + raw[i + 1:])
        elif kind == "rgb":
            cv2.imwrite(str(p), np.zeros((H, W, 3), np.uint8))
        elif kind == "float":
            p.write_bytes(cv2.imencode(".tiff", np.zeros((H, W), np.float32))[1].tobytes())
        elif kind == "size":
            cv2.imwrite(str(p), np.zeros((W, H), np.uint16))
        else:
            p.write_bytes(data.draw(st.binary(max_size=200)))
        only_s2p_errors(lambda: read_png_folder(d / "png"))


FILE_READERS = {"g.csv": read_ground_points, "p.csv": read_poses, "m.txt": read_mots,
                "m.json": read_coco}


@FUZZ
@given(st.binary(max_size=400), st.sampled_from(sorted(FILE_READERS)))
def test_file_readers_random_bytes(blob, name):
    """Ground points, poses.csv, MOTS and COCO files of random bytes."""
    with folder() as d:
        (d / name).write_bytes(blob)
        only_s2p_errors(lambda: FILE_READERS[name](d / name))


# --- poses.csv ------------------------------------------------------------------------------------

@st.composite
def pose_tables(draw):
    n = draw(st.integers(0, 12))
    frames = sorted(draw(st.lists(st.integers(0, 10 ** 9), min_size=n, max_size=n)))
    tids = draw(st.lists(st.integers(-1, 10 ** 12), min_size=n, max_size=n, unique=True))
    xyz = draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n))
    heading = draw(st.lists(st.one_of(st.floats(-4, 4), st.just(math.nan)), min_size=n, max_size=n))
    size = draw(st.lists(st.tuples(*[st.one_of(st.floats(0.01, 100), st.just(math.nan))] * 3),
                         min_size=n, max_size=n))
    cls = draw(st.lists(st.sampled_from(["car", "pedestrian", "bicyclist"]), min_size=n, max_size=n))
    return PoseTable(frames, tids, np.array(cls, object), np.array(xyz).reshape(-1, 3), heading,
                     np.array(size).reshape(-1, 3))


@FUZZ
@given(pose_tables())
def test_poses_round_trip(t):
    with folder() as d:
        write_poses(d / "p.csv", t)
        r = read_poses(d / "p.csv")
        assert np.array_equal(r.frame, t.frame) and np.array_equal(r.track_id, t.track_id)
        assert list(r.cls) == list(t.cls) and np.array_equal(r.xyz, t.xyz)
        assert np.array_equal(r.heading, t.heading, equal_nan=True)
        assert np.array_equal(r.size, t.size, equal_nan=True)


@FUZZ
@given(st.data())
def test_poses_near_valid(data):
    with folder() as d:
        s = write_scene(d, frames=3, users=2)
        p = s.gt_path
        p.write_text(mutate_text(data, p.read_text(), ","))
        r = only_s2p_errors(lambda: read_poses(p, known_classes=["car", "pedestrian", "bicyclist"]))
        if r is not None and len(r):
            assert np.isfinite(r.xyz).all() and not np.isinf(r.heading).any()
            assert r.size is None or ((r.size > 0) | np.isnan(r.size)).all()


# --- UTOCS folders --------------------------------------------------------------------------------

@FUZZ
@given(st.data())
def test_utocs_near_valid(data):
    from seg2pose.io.utocs import import_utocs

    with folder() as d:
        src = write_utocs(d / "u", frames=2)
        which = data.draw(st.sampled_from(["cameras.json", "positions/000001.json", "ground_points.txt"]))
        p = src / which
        if which.endswith(".json"):
            p.write_text(mutate_json(data, json.loads(p.read_text())))
        else:
            p.write_text(mutate_text(data, p.read_text(), ","))
        out = d / "out"
        s = only_s2p_errors(lambda: import_utocs(src, out, log=lambda *a: None))
        if s is None:
            assert not (out / "scene.json").exists()
        else:  # an accepted recording gives a scene s2p can load, and nothing outside out/
            load_scene(out)
            assert sorted(x.name for x in d.iterdir()) == ["out", "u"]


@FUZZ
@given(st.binary(max_size=300), st.sampled_from(["cameras.json", "positions/000000.json"]))
def test_utocs_random_bytes(blob, which):
    from seg2pose.io.utocs import import_utocs

    with folder() as d:
        src = write_utocs(d / "u", frames=1)
        (src / which).write_bytes(blob)
        only_s2p_errors(lambda: import_utocs(src, d / "out", log=lambda *a: None))


# --- MCAP import ----------------------------------------------------------------------------------

ROW = {"frame": 0, "track_id": 1, "class": "car", "x": 1.5, "y": -2.25, "z": 0.0,
       "heading": 0.5, "l": 4.0, "w": 2.0, "h": 1.5}


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), finite, finite), min_size=1, max_size=8,
                unique_by=lambda r: r[0]))
def test_mcap_import_round_trip(rows):
    from s2p_review.mcap_import import import_mcap

    msgs = [{"frame": f, "rows": [dict(ROW, frame=f, x=x, y=y)]} for f, x, y in sorted(rows)]
    with folder() as d:
        f = write_s2p_mcap(d / "x.mcap", {"version": 1}, "ground_points.csv", msgs)
        run = import_mcap(f, d / "out")
        t = read_poses(run / "poses.csv")
        assert t.frame.tolist() == sorted(r[0] for r in rows)
        assert t.xyz[:, :2].tolist() == [[x, y] for _, x, y in sorted(rows)]


@FUZZ
@given(st.data())
def test_mcap_import_near_valid(data):
    from s2p_review.mcap_import import import_mcap

    msgs = [{"frame": f, "rows": [dict(ROW, frame=f, track_id=t) for t in (1, 2)]} for f in range(3)]
    scene_d = {"version": 1, "ground_points": "ground_points.csv"}
    which = data.draw(st.sampled_from(["poses", "scene", "bytes"]))
    with folder() as d:
        if which == "poses":
            i = data.draw(st.integers(0, len(msgs) - 1))
            msgs[i] = mutate_json(data, msgs[i])  # the text of one message, maybe not JSON
        elif which == "scene":
            with contextlib.suppress(ValueError):
                scene_d = json.loads(mutate_json(data, scene_d))
        gname = scene_d.get("ground_points") if isinstance(scene_d, dict) else None
        f = write_s2p_mcap(d / "x.mcap", scene_d, gname if isinstance(gname, str) and gname else "g.csv", msgs)
        if which == "bytes":
            raw = f.read_bytes()
            f.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1))])
        run = only_s2p_errors(lambda: import_mcap(f, d / "out" / "scene"))
        # nothing is ever written outside the output folder
        assert sorted(p.name for p in d.iterdir()) in (["x.mcap"], ["out", "x.mcap"])
        if run is not None:
            read_poses(run / "poses.csv")


@FUZZ
@given(st.binary(max_size=400))
def test_mcap_import_random_bytes(blob):
    from s2p_review.mcap_import import import_mcap

    with folder() as d:
        (d / "x.mcap").write_bytes(blob)
        only_s2p_errors(lambda: import_mcap(d / "x.mcap", d / "out"))


# --- each reader on one file: random text, near-valid fields, exact parses of valid files -------
# (hypothesis draws in tmp_path, the io_fixtures' 24 x 32 masks)

FUZZ_FILES = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _fuzz(tmp_path, name, data, reader, writer=None, same=None):
    """Read fuzzed bytes: either the project's own error, or a result that survives its own
    round trip exactly (``writer`` then ``reader`` again, compared by ``same``)."""
    p = tmp_path / name
    p.write_bytes(data)
    try:
        got = reader(p)
    except S2PError:
        return None
    if writer is not None:
        q = tmp_path / f"again-{name}"
        writer(q, got)
        same(reader(q), got)
    return got


def same_poses(a: PoseTable, b: PoseTable):
    for col in ("frame", "track_id", "cls", "xyz", "heading", "size"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))


def write_ground(path, pts):
    from seg2pose.io.scene import write_ground_points

    write_ground_points(path, pts)


def _text_like():
    # random bytes, and byte strings built from the formats' own alphabet (gets past decoding)
    alphabet = st.sampled_from(list(b"0123456789 ,.-\n#abcxyzO_PQ[]{}\":e") + [0, 255, 0xC3])
    return st.one_of(st.binary(max_size=300), st.lists(alphabet, max_size=300).map(bytes))


@FUZZ_FILES
@given(_text_like())
def test_fuzz_mots(tmp_path, data):
    _fuzz(tmp_path, "m.txt", data, lambda p: read_mots(p, {1, 2, 3}), write_mots, same_masks)


@FUZZ_FILES
@given(st.one_of(_text_like(), st.binary(max_size=40).map(lambda b: b"0 1 1 2 3 " + b + b"\n")))
def test_fuzz_mots_rle(tmp_path, data):
    _fuzz(tmp_path, "m.txt", data, read_mots, write_mots, same_masks)


@FUZZ_FILES
@given(_text_like())
def test_fuzz_poses(tmp_path, data):
    _fuzz(tmp_path, "p.csv", b"frame,track_id,class,x,y,z,heading\n" + data, read_poses, write_poses,
          same_poses)
    _fuzz(tmp_path, "p.csv", data, read_poses, write_poses, same_poses)


@FUZZ_FILES
@given(_text_like())
def test_fuzz_ground(tmp_path, data):
    _fuzz(tmp_path, "g.csv", data, read_ground_points, write_ground, np.testing.assert_array_equal)


@FUZZ_FILES
@given(_text_like())
def test_fuzz_coco(tmp_path, data):
    _fuzz(tmp_path, "c.json", data, read_coco)


# --- valid inputs, written by hand here, parse to exactly the values written -------------------

finite_m = st.floats(-1e6, 1e6, allow_nan=False)  # the readers' range for positions, metres


@FUZZ_FILES
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(-1, 10**6),
                          st.sampled_from(["car", "pedestrian", "bicyclist"]), finite_m, finite_m, finite_m,
                          st.floats(allow_infinity=False)), max_size=12,
                unique_by=lambda r: (r[0], r[1])),  # one row per road user and frame
       st.booleans(), st.sampled_from([",", ", "]))
def test_valid_poses_parse_exactly(tmp_path, rows, with_size, sep):
    rows = sorted(rows, key=lambda r: r[0])
    head = "frame,track_id,class,x,y,z,heading" + (",l,w,h" if with_size else "")
    lines = [head] + [sep.join([str(f), str(t), c] + [repr(v) for v in (x, y, z, h)]
                               + (["4.5", "1.8", "1.5"] if with_size else []))
                      for f, t, c, x, y, z, h in rows]
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    got = read_poses(tmp_path / "p.csv")
    assert got.frame.tolist() == [r[0] for r in rows] and got.track_id.tolist() == [r[1] for r in rows]
    assert got.cls.tolist() == [r[2] for r in rows]
    np.testing.assert_array_equal(got.xyz, np.array([r[3:6] for r in rows], float).reshape(-1, 3))
    np.testing.assert_array_equal(got.heading, np.array([r[6] for r in rows], float))
    if with_size:
        np.testing.assert_array_equal(got.size, np.tile([4.5, 1.8, 1.5], (len(rows), 1)))
    else:
        assert got.size is None


@FUZZ_FILES
@given(st.lists(st.tuples(*[st.floats(-1e5, 1e5, allow_nan=False)] * 3), min_size=3, max_size=12,
                unique_by=lambda p: (p[0], p[1])), st.booleans())
def test_valid_ground_points_parse_exactly(tmp_path, pts, header):
    text = ("x,y,z\n" if header else "") + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts)
    (tmp_path / "g.csv").write_text(text)
    np.testing.assert_array_equal(read_ground_points(tmp_path / "g.csv"), np.array(pts, float))


@FUZZ_FILES
@given(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 99), st.integers(1, 3),
                          st.integers(0, IO_H - 1), st.integers(0, IO_W - 1), st.integers(1, 6),
                          st.integers(1, 6)), min_size=1, max_size=10,
                unique_by=lambda b: (b[0], b[1])))  # one mask per road user and frame
def test_valid_mots_parse_exactly(tmp_path, boxes):
    boxes = sorted(boxes, key=lambda b: b[0])
    masks = []
    for _, _, _, y, x, h, w in boxes:
        m = np.zeros((IO_H, IO_W), np.uint8)
        m[y:y + h, x:x + w] = 1
        masks.append(m)
    lines = [f"{f} {t} {c} {IO_H} {IO_W} {encode(m).decode()}" for (f, t, c, *_), m in zip(boxes, masks)]
    (tmp_path / "m.txt").write_text("\n".join(lines) + "\n")
    got = read_mots(tmp_path / "m.txt")
    assert got.frame.tolist() == [b[0] for b in boxes] and got.track_id.tolist() == [b[1] for b in boxes]
    assert got.class_id.tolist() == [b[2] for b in boxes] and (got.height, got.width) == (IO_H, IO_W)
    for r, m in zip(got.rles, masks):
        np.testing.assert_array_equal(decode(r, IO_H, IO_W), m)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
    max_leaves=20)


@FUZZ_FILES
@given(json_values, st.sampled_from(["frame", "category_id", "segmentation", "track_id", "score",
                                     "image_id"]))
def test_fuzz_coco_structured(tmp_path, value, key):
    rec = {"frame": 0, "category_id": 1, "segmentation": {"size": [2, 3], "counts": RLE}}
    rec[key] = value
    for data in ([rec], {"annotations": [rec], "images": [value]}, value):
        _fuzz(tmp_path, "c.json", json.dumps(data).encode(), read_coco)


@FUZZ_FILES
@given(json_values, st.sampled_from(["version", "fps", "cameras", "classes", "configs", "splits",
                                     "ground_points", "extra", "c0", "c0.K", "c0.distortion",
                                     "c1.P", "c0.width"]))
def test_fuzz_scene_json(tmp_path, value, key):
    if not (tmp_path / "scene.json").exists():
        make_scene(tmp_path)
    d = json.loads((tmp_path / "scene.json").read_text())
    if key.startswith("c0.") or key.startswith("c1."):
        d["cameras"][int(key[1])][key[3:]] = value
    elif key == "c0":
        d["cameras"][0] = value
    else:
        d[key] = value
    (tmp_path / "s2").mkdir(exist_ok=True)
    (tmp_path / "s2" / "ground_points.csv").write_bytes((tmp_path / "ground_points.csv").read_bytes())
    try:
        (tmp_path / "s2" / "scene.json").write_text(json.dumps(d))
    except ValueError:
        return
    try:
        load_scene(tmp_path / "s2")
    except S2PError:
        pass


@FUZZ_FILES
@given(st.binary(max_size=200))
def test_fuzz_scene_bytes(tmp_path, data):
    (tmp_path / "scene.json").write_bytes(data)
    try:
        load_scene(tmp_path)
    except S2PError:
        pass


@FUZZ_FILES
@given(st.binary(max_size=200))
def test_fuzz_png(tmp_path, data):
    (tmp_path / "png").mkdir(exist_ok=True)
    (tmp_path / "png" / "000001.png").write_bytes(data)
    try:
        read_png_folder(tmp_path / "png")
    except S2PError:
        pass
