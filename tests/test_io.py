"""File formats: round trips, bad-input messages, and fuzzing with random bytes."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seg2pose.geometry.camera import Camera, Rig
from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import atomic_write_text, check_writable
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import MaskTable, iter_mots, read_mots, write_mots
from seg2pose.io.png import read_png_folder, write_png_folder
from seg2pose.io.poses import PoseTable, read_poses, write_poses
from seg2pose.io.scene import ClassSpec, Scene, load_scene, read_ground_points
from seg2pose.structures.masks import decode, encode

H, W = 24, 32


def masks_table(seed=0, overlap=True):
    """3 frames of small box masks (non-overlapping unless ``overlap``)."""
    rng = np.random.default_rng(seed)
    fr, tid, cid, rles = [], [], [], []
    for f in (0, 1, 3):
        for k in range(3):
            m = np.zeros((H, W), np.uint8)
            x0 = 10 * k + (0 if not overlap else int(rng.integers(0, 4)))
            y0 = int(rng.integers(0, 10))
            m[y0:y0 + int(rng.integers(2, 12)), x0:x0 + int(rng.integers(1, 9 if overlap else 10))] = 1
            fr.append(f)
            tid.append(k + 5)
            cid.append(1 + k % 3)
            rles.append(encode(m))
    return MaskTable(fr, tid, cid, H, W, rles)


def same_masks(a: MaskTable, b: MaskTable, ordered=True):
    assert (a.height, a.width) == (b.height, b.width)
    ka = list(zip(a.frame.tolist(), a.track_id.tolist(), a.class_id.tolist(), a.rles))
    kb = list(zip(b.frame.tolist(), b.track_id.tolist(), b.class_id.tolist(), b.rles))
    if not ordered:
        ka, kb = sorted(ka), sorted(kb)
    assert ka == kb


# --- round trips ---------------------------------------------------------------------------------

def test_mots_round_trip_and_streaming(tmp_path):
    t = masks_table()
    write_mots(tmp_path / "m.txt", t)
    same_masks(read_mots(tmp_path / "m.txt"), t)
    frames = [f for f, _ in iter_mots(tmp_path / "m.txt")]
    assert frames == [0, 1, 3]
    assert len(read_mots(tmp_path / "m.txt", frame_range=(1, 2))) == 3


def test_coco_round_trip(tmp_path):
    t = masks_table()
    t.score = np.linspace(0.5, 1.0, len(t))
    write_coco(tmp_path / "m.json", t)
    r = read_coco(tmp_path / "m.json")
    same_masks(r, t)
    assert np.array_equal(r.score, t.score)
    # a COCO dataset object with uncompressed counts and image -> frame ids
    m = np.zeros((H, W), np.uint8)
    m[2:5, 3:4] = 1
    counts = [3 * H + 2, 3, H * W - 3 * H - 5]
    data = {"images": [{"id": 7, "frame_id": 42}],
            "annotations": [{"image_id": 7, "category_id": 3,
                             "segmentation": {"size": [H, W], "counts": counts}}]}
    (tmp_path / "d.json").write_text(json.dumps(data))
    r = read_coco(tmp_path / "d.json")
    assert r.frame.tolist() == [42] and r.track_id.tolist() == [-1] and r.class_id.tolist() == [3]
    assert np.array_equal(decode(r.rles[0], H, W), m)


def test_png_round_trip(tmp_path):
    t = masks_table(overlap=False)
    written = write_png_folder(tmp_path / "png", t)
    assert [p.name for p in written] == ["000000.png", "000001.png", "000003.png"]
    r = read_png_folder(tmp_path / "png")
    same_masks(r, t, ordered=False)
    import cv2
    img = cv2.imread(str(written[0]), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and set(np.unique(img)) == {0, 1005, 2006, 3007}


def test_png_rejects_untracked(tmp_path):
    t = masks_table()
    t.track_id[0] = -1
    with pytest.raises(InputError, match="track id -1"):
        write_png_folder(tmp_path / "png", t)


def test_poses_round_trip_exact(tmp_path):
    rng = np.random.default_rng(1)
    n = 20
    t = PoseTable(np.sort(rng.integers(0, 9, n)), rng.permutation(n),
                  np.array(["car", "pedestrian"] * 10, object), rng.normal(size=(n, 3)) * 1e3,
                  np.r_[rng.uniform(-3, 3, n - 1), np.nan], rng.uniform(0.1, 5, (n, 3)))
    write_poses(tmp_path / "p.csv", t)
    r = read_poses(tmp_path / "p.csv")
    assert np.array_equal(r.frame, t.frame) and np.array_equal(r.track_id, t.track_id)
    assert list(r.cls) == list(t.cls)
    assert np.array_equal(r.xyz, t.xyz) and np.array_equal(r.size, t.size)
    assert np.array_equal(r.heading, t.heading, equal_nan=True)


def make_scene(root, **kw):
    cam = Camera.look_at("c0", [0, -10, 5], [0, 0, 0], 500.0, 640, 480)
    cam1 = Camera.from_P("c1", Camera.look_at("x", [1, -10, 5], [0, 0, 0], 400.0, 320, 240).P, 320, 240)
    pts = np.array([[0, 0, 0], [1, 0, 0.1], [0, 1, 0.2], [5, 5, -0.3]], float)
    s = Scene(root=root, name="t", fps=10.0,
              rig=Rig({"c0": cam, "c1": cam1}, {"stereo": ["c0", "c1"]}, "r"),
              ground_points=pts,
              classes=[ClassSpec(1, "pedestrian", 0.8), ClassSpec(3, "car", 0.7)],
              splits={"train": (0, 9)}, extra={"k": 1}, **kw)
    s.save()
    return s


def test_scene_round_trip(tmp_path):
    s = make_scene(tmp_path)
    r = load_scene(tmp_path)
    assert r.to_dict() == json.loads(json.dumps(s.to_dict()))
    assert r.fingerprint() == s.fingerprint()
    assert np.allclose(r.cameras["c1"].P / r.cameras["c1"].P[2, 3], s.cameras["c1"].P / s.cameras["c1"].P[2, 3])
    assert np.array_equal(r.ground_points, s.ground_points)
    assert r.split_range("train") == (0, 9) and r.split_range(None) is None


def test_atomic_and_check_writable(tmp_path):
    p = tmp_path / "a.txt"
    atomic_write_text(p, "x")
    with pytest.raises(S2PError, match="--force"):
        check_writable(p, force=False)
    assert check_writable(p, force=True) == p
    assert [q.name for q in tmp_path.iterdir()] == ["a.txt"]  # no temporary left behind


# --- bad input names file, line/field and what was expected -------------------------------------

def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


RLE = encode(np.ones((2, 3), np.uint8)).decode()


@pytest.mark.parametrize("text,match", [
    (f"0 1 1 2 3\n", r"m.txt:1: expected 6 fields"),
    (f"0 1 1 2 3 {RLE}\n0 1 1 2 4 {RLE}\n", r"m.txt:2: image size 2x4 differs"),
    (f"0 1 1 2 3 {RLE}\n0 1 1 3 3 {RLE}\n", r"m.txt:2: image size 3x3 differs"),
    (f"0 1 1 4 3 {RLE}\n", r"m.txt:1: RLE covers 6 pixels but height\*width = 12"),
    (f"0 1 9 2 3 {RLE}\n", r"m.txt:1: unknown class_id 9"),
    (f"5 1 1 2 3 {RLE}\n# c\n4 1 1 2 3 {RLE}\n", r"m.txt:3: frame 4 comes after frame 5"),
    (f"0 1 1 0 3 {RLE}\n", r"m.txt:1: non-positive image size"),
    ("0 1 1 2 3 ~~\n", r"m.txt:1: .*COCO alphabet"),
    ("a 1 1 2 3 x\n", r"m.txt:1: expected integers"),
])
def test_mots_bad_input(tmp_path, text, match):
    p = write(tmp_path, "m.txt", text)
    with pytest.raises(InputError, match=match):
        read_mots(p, known_classes={1, 2, 3})


@pytest.mark.parametrize("text,match", [
    ("x,y,z\n0,0,0\n1,0,0\n", r"g.csv: need at least 3 ground points"),
    ("x,y,z\n0,0,0\n1,0,0\n0,1,0\n1,0,0\n", r"g.csv:3: duplicate ground point"),
    ("0,0,0\n1,0,nan\n0,1,0\n", r"g.csv:2: NaN or inf"),
    ("0,0,0\n1,0\n", r"g.csv:2: expected 3 fields"),
    ("0,0,0\n1,a,0\n", r"g.csv:2: expected numbers"),
])
def test_ground_bad_input(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        read_ground_points(write(tmp_path, "g.csv", text))


def test_poses_bad_input(tmp_path):
    head = "frame,track_id,class,x,y,z,heading\n"
    with pytest.raises(InputError, match=r"p.csv:1: expected header"):
        read_poses(write(tmp_path, "p.csv", "frame,id\n"))
    with pytest.raises(InputError, match=r"p.csv:3: frame 0 comes after frame 2"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,car,0,0,0,0\n0,1,car,0,0,0,0\n"))
    with pytest.raises(InputError, match=r"p.csv:2: field 'class': unknown class 'tram'"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,tram,0,0,0,0\n"), known_classes={"car"})
    with pytest.raises(InputError, match=r"p.csv:2: x, y, z must be finite"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,car,inf,0,0,0\n"))


def scene_json_with(tmp_path, mutate):
    make_scene(tmp_path)
    d = json.loads((tmp_path / "scene.json").read_text())
    mutate(d)
    (tmp_path / "scene.json").write_text(json.dumps(d))


@pytest.mark.parametrize("mutate,match", [
    (lambda d: d["cameras"][1].update(P=[[1, 0, 0, 0], [0, 1, 0, 0]]), r"field 'cameras\[c1\].P': expected shape \(3, 4\)"),
    (lambda d: d["cameras"][1].update(P=[[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0]]), r"field 'cameras\[c1\].P': P has rank < 3"),
    (lambda d: d["cameras"][0].update(width=0), r"field 'cameras\[c0\].width': expected an integer in \[1, 1048576\], got 0"),
    (lambda d: d["cameras"][0]["K"][0].__setitem__(0, float("nan")), r"scene.json: field 'cameras\[c0\].K': NaN or inf"),
    (lambda d: d.update(version=2), r"field 'version': unsupported version 2"),
    (lambda d: d.update(fps=-1), r"field 'fps'"),
    (lambda d: d.update(classes={"a": 1}), r"field 'classes'"),
    (lambda d: d["classes"][0].update(default_height="x"), r"field 'classes\[0\].default_height': expected a number in \[0, 20\]"),
    (lambda d: d.update(configs={"m": ["nope"]}), r"field 'configs.m': configuration 'm' names unknown cameras"),
    (lambda d: d.update(splits={"train": [5, 1]}), r"field 'splits.train'"),
    (lambda d: d["cameras"][0].update(distortion={"k1": "x"}), r"field 'cameras\[c0\].distortion.k1'"),
    (lambda d: d["cameras"][0].pop("R"), r"field 'cameras\[c0\].R': missing"),
])
def test_scene_bad_input(tmp_path, mutate, match):
    scene_json_with(tmp_path, mutate)
    with pytest.raises(InputError, match=match):
        load_scene(tmp_path)


def test_coco_bad_input(tmp_path):
    rec = {"frame": 0, "category_id": 1, "segmentation": {"size": [2, 3], "counts": RLE}}
    cases = [
        ({**rec, "category_id": 9}, r"field '\[0\].category_id': unknown class 9"),
        ({**rec, "segmentation": {"size": [4, 3], "counts": RLE}}, r"field '\[0\].segmentation.counts': RLE covers 6"),
        ({**rec, "frame": "a"}, r"field '\[0\].frame': expected an integer"),
        ({**rec, "segmentation": [[1, 2, 3]]}, r"field '\[0\].segmentation'"),
    ]
    for r, match in cases:
        p = tmp_path / "c.json"
        p.write_text(json.dumps([rec, r][1:]))
        with pytest.raises(InputError, match=match):
            read_coco(p, known_classes={1, 2, 3})


# --- fuzzing: random bytes raise the project's own errors, nothing else -------------------------

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


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


@FUZZ
@given(_text_like())
def test_fuzz_mots(tmp_path, data):
    _fuzz(tmp_path, "m.txt", data, lambda p: read_mots(p, {1, 2, 3}), write_mots, same_masks)


@FUZZ
@given(st.one_of(_text_like(), st.binary(max_size=40).map(lambda b: b"0 1 1 2 3 " + b + b"\n")))
def test_fuzz_mots_rle(tmp_path, data):
    _fuzz(tmp_path, "m.txt", data, read_mots, write_mots, same_masks)


@FUZZ
@given(_text_like())
def test_fuzz_poses(tmp_path, data):
    _fuzz(tmp_path, "p.csv", b"frame,track_id,class,x,y,z,heading\n" + data, read_poses, write_poses,
          same_poses)
    _fuzz(tmp_path, "p.csv", data, read_poses, write_poses, same_poses)


@FUZZ
@given(_text_like())
def test_fuzz_ground(tmp_path, data):
    _fuzz(tmp_path, "g.csv", data, read_ground_points, write_ground, np.testing.assert_array_equal)


@FUZZ
@given(_text_like())
def test_fuzz_coco(tmp_path, data):
    _fuzz(tmp_path, "c.json", data, read_coco)


# --- valid inputs, written by hand here, parse to exactly the values written -------------------

finite = st.floats(-1e6, 1e6, allow_nan=False)  # the readers' range for positions, metres


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10**6), st.integers(-1, 10**6),
                          st.sampled_from(["car", "pedestrian", "bicyclist"]), finite, finite, finite,
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


@FUZZ
@given(st.lists(st.tuples(*[st.floats(-1e5, 1e5, allow_nan=False)] * 3), min_size=3, max_size=12,
                unique_by=lambda p: (p[0], p[1])), st.booleans())
def test_valid_ground_points_parse_exactly(tmp_path, pts, header):
    text = ("x,y,z\n" if header else "") + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts)
    (tmp_path / "g.csv").write_text(text)
    np.testing.assert_array_equal(read_ground_points(tmp_path / "g.csv"), np.array(pts, float))


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 99), st.integers(1, 3),
                          st.integers(0, H - 1), st.integers(0, W - 1), st.integers(1, 6),
                          st.integers(1, 6)), min_size=1, max_size=10,
                unique_by=lambda b: (b[0], b[1])))  # one mask per road user and frame
def test_valid_mots_parse_exactly(tmp_path, boxes):
    boxes = sorted(boxes, key=lambda b: b[0])
    masks = []
    for _, _, _, y, x, h, w in boxes:
        m = np.zeros((H, W), np.uint8)
        m[y:y + h, x:x + w] = 1
        masks.append(m)
    lines = [f"{f} {t} {c} {H} {W} {encode(m).decode()}" for (f, t, c, *_), m in zip(boxes, masks)]
    (tmp_path / "m.txt").write_text("\n".join(lines) + "\n")
    got = read_mots(tmp_path / "m.txt")
    assert got.frame.tolist() == [b[0] for b in boxes] and got.track_id.tolist() == [b[1] for b in boxes]
    assert got.class_id.tolist() == [b[2] for b in boxes] and (got.height, got.width) == (H, W)
    for r, m in zip(got.rles, masks):
        np.testing.assert_array_equal(decode(r, H, W), m)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=5),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=4),
    max_leaves=20)


@FUZZ
@given(json_values, st.sampled_from(["frame", "category_id", "segmentation", "track_id", "score",
                                     "image_id"]))
def test_fuzz_coco_structured(tmp_path, value, key):
    rec = {"frame": 0, "category_id": 1, "segmentation": {"size": [2, 3], "counts": RLE}}
    rec[key] = value
    for data in ([rec], {"annotations": [rec], "images": [value]}, value):
        _fuzz(tmp_path, "c.json", json.dumps(data).encode(), read_coco)


@FUZZ
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


@FUZZ
@given(st.binary(max_size=200))
def test_fuzz_scene_bytes(tmp_path, data):
    (tmp_path / "scene.json").write_bytes(data)
    try:
        load_scene(tmp_path)
    except S2PError:
        pass


@FUZZ
@given(st.binary(max_size=200))
def test_fuzz_png(tmp_path, data):
    (tmp_path / "png").mkdir(exist_ok=True)
    (tmp_path / "png" / "000001.png").write_bytes(data)
    try:
        read_png_folder(tmp_path / "png")
    except S2PError:
        pass


# --- commands ------------------------------------------------------------------------------------

def test_cli_convert_masks_round_trip(tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    t = masks_table(overlap=False)
    write_mots(tmp_path / "a.txt", t)
    run = CliRunner().invoke
    r = run(app, ["convert-masks", str(tmp_path / "a.txt"), "-o", str(tmp_path / "b.json"), "--format", "coco"])
    assert r.exit_code == 0, r.output
    assert "9 masks in 3 frames (32x24)" in r.output
    assert run(app, ["convert-masks", str(tmp_path / "b.json"), "-o", str(tmp_path / "png"), "-f", "png"]).exit_code == 0
    assert run(app, ["convert-masks", str(tmp_path / "png"), "-o", str(tmp_path / "c.txt"), "-f", "mots"]).exit_code == 0
    same_masks(read_mots(tmp_path / "c.txt"), t, ordered=False)
    r = run(app, ["convert-masks", str(tmp_path / "png"), "-o", str(tmp_path / "c.txt"), "-f", "mots"])
    assert r.exit_code != 0 and "--force" in str(r.exception)


def test_heights_bisection_writes_scene_json(tmp_path):
    """A camera over flat ground; pedestrians and cars as exact box masks; ``s2p heights``
    moves the default heights so that about half the normal positions are closer."""
    import cv2

    from seg2pose.method.heights import update_default_heights

    cam = Camera.look_at("c0", [0, -15, 8], [0, 10, 0], 800.0, 960, 540)
    pts = np.array([[x, y, 0.0] for x in range(-20, 21, 4) for y in range(-10, 41, 4)], float)
    s = Scene(root=tmp_path, name="t", fps=10.0, rig=Rig({"c0": cam}, {}, "r"), ground_points=pts,
              classes=[ClassSpec(1, "pedestrian", 0.3), ClassSpec(3, "car", 1.4)],
              splits={"train": (0, 39)})
    s.save()
    rng = np.random.default_rng(0)
    rows, masks = [], []
    for f in range(40):
        for k, (cname, cid, (l, w, h)) in enumerate([("pedestrian", 1, (0.5, 0.5, 1.8)),
                                                      ("car", 3, (4.5, 1.8, 1.5))]):
            x, y, hd = rng.uniform(-8, 8), rng.uniform(0, 30), rng.uniform(-3, 3)
            c, sn = np.cos(hd), np.sin(hd)
            corners = np.array([(x + c * a - sn * b, y + sn * a + c * b, z) for a in (-l / 2, l / 2)
                                for b in (-w / 2, w / 2) for z in (0, h)])
            uv, _, _ = cam.project_points(corners)
            m = np.zeros((540, 960), np.uint8)
            cv2.fillConvexPoly(m, cv2.convexHull(np.round((uv - 0.5) * 16).astype(np.int32)), 1, shift=4)
            rows.append((f, k, cname, x, y, hd, l, w, h))
            masks.append((f, k, cid, encode(m)))
    f, k, cn, x, y, hd, l, w, h = zip(*rows)
    write_poses(tmp_path / "gt" / "poses.csv",
                PoseTable(f, k, np.array(cn, object), np.column_stack([x, y, np.zeros(len(x))]), hd,
                          np.column_stack([l, w, h])))
    f, k, cid, rl = zip(*masks)
    (tmp_path / "masks").mkdir()
    write_mots(tmp_path / "masks" / "c0.txt", MaskTable(f, k, cid, 540, 960, list(rl)))
    lines = []
    rep = update_default_heights(load_scene(tmp_path), "train", "bbox", log=lines.append)
    assert rep["pedestrian"]["n"] == 40 and rep["car"]["n"] == 40
    for c in ("pedestrian", "car"):
        assert 0.4 <= rep[c]["closer_share"] <= 0.6
    # a box's projected bbox centre sits near its middle: heights near half the box height
    assert 0.6 < rep["pedestrian"]["new"] < 1.2 and 0.5 < rep["car"]["new"] < 1.0
    d = json.loads((tmp_path / "scene.json").read_text())
    assert [c["default_height"] for c in d["classes"]] == [rep["pedestrian"]["new"], rep["car"]["new"]]
    assert any("pedestrian: 0.300 m ->" in ln for ln in lines)


def test_iter_mots_blocks_keep_frames_whole(tmp_path, monkeypatch):
    import seg2pose.io.mots as M

    t = masks_table()
    write_mots(tmp_path / "m.txt", t)
    monkeypatch.setattr(M, "_BLOCK", 2)  # blocks end only at frame boundaries
    got = [(f, len(x), x.frame.tolist()) for f, x in iter_mots(tmp_path / "m.txt")]
    assert got == [(0, 3, [0, 0, 0]), (1, 3, [1, 1, 1]), (3, 3, [3, 3, 3])]
    lines = (tmp_path / "m.txt").read_text().splitlines()
    parts = lines[7].split()
    lines[7] = " ".join(parts[:5] + [RLE])  # a 2x3 mask's runs on a 24x32 line
    (tmp_path / "m.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"m.txt:8: RLE covers 6 pixels but height\*width = 768"):
        list(iter_mots(tmp_path / "m.txt"))
