"""scene.json and the ground points have one schema (seg2pose/io/scene_schema.py) that their
reader (``load_scene``) and their writers check: for each bad field the writer refuses in one line
naming the file and the field, with nothing written (the old files intact), and the reader
refuses the same content written by hand, naming the same field; a scene the writer accepts
the reader loads equal (hypothesis)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from fuzz_fixtures import FUZZ, folder
from hypothesis import given, settings
from hypothesis import strategies as st
from io_fixtures import make_scene

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, OpenCVDistortion, Rig
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, load_scene, write_ground_points

SJ, GP = "scene.json", "ground_points.csv"


def _cam(s: Scene, name: str = "c0") -> Camera:
    return s.cameras[name]


def _set(obj, **kw):
    for k, v in kw.items():
        setattr(obj, k, v)


# case -> (change to a saved scene, the file refused, what both messages name: a field, or the
# ground points file's words)
CASES = {
    "fps 0": (lambda s: _set(s, fps=0.0), SJ, "field 'fps'"),
    "fps nan": (lambda s: _set(s, fps=math.nan), SJ, "field 'fps'"),
    "fps 2e6": (lambda s: _set(s, fps=2e6), SJ, "field 'fps'"),
    "camera named ../x": (lambda s: _set(_cam(s), name="../x"), SJ, "field 'cameras[0].name'"),
    "camera named ''": (lambda s: _set(_cam(s), name=""), SJ, "field 'cameras[0].name'"),
    "width 2^21": (lambda s: _set(_cam(s), width=2 ** 21), SJ, "field 'cameras[c0].width'"),
    "K nan": (lambda s: _cam(s).K.__setitem__((0, 0), math.nan), SJ, "field 'cameras[c0].K'"),
    "R not a rotation": (lambda s: _set(_cam(s), R=2 * _cam(s).R), SJ, "field 'cameras[c0].R'"),
    "distortion 1e300": (lambda s: _set(_cam(s), distortion=OpenCVDistortion(k1=1e300)), SJ,
                         "field 'cameras[c0].distortion.k1'"),
    "two cameras named c0": (lambda s: _set(_cam(s, "c1"), name="c0"), SJ, "field 'cameras[1].name'"),
    "configuration of no camera": (lambda s: s.rig.configs.update(m=["nope"]), SJ, "field 'configs.m'"),
    "configuration named ..": (lambda s: s.rig.configs.update({"..": ["c0"]}), SJ, "field 'configs...'"),
    "class id 0": (lambda s: _set(s.classes[0], id=0), SJ, "field 'classes[0].id'"),
    "class id 2^16": (lambda s: _set(s.classes[1], id=65536), SJ, "field 'classes[1].id'"),
    "class named a/b": (lambda s: _set(s.classes[0], name="a/b"), SJ, "field 'classes[0].name'"),
    "default height 25 m": (lambda s: _set(s.classes[0], default_height=25.0), SJ,
                            "field 'classes[0].default_height'"),
    "default height nan": (lambda s: _set(s.classes[1], default_height=math.nan), SJ,
                           "field 'classes[1].default_height'"),
    "class id twice": (lambda s: _set(s.classes[1], id=1), SJ, "field 'classes'"),
    "split last before first": (lambda s: _set(s, splits={"train": (9, 0)}), SJ, "field 'splits.train'"),
    "split frame -1": (lambda s: _set(s, splits={"val": (-1, 3)}), SJ, "field 'splits.val'"),
    "start time without zone": (lambda s: _set(s, start_time="2021-06-14T08:00:00"), SJ,
                                "field 'start_time'"),
    "start time 2300": (lambda s: _set(s, start_time="2300-01-01T00:00:00Z"), SJ, "field 'start_time'"),
    "ground file outside": (lambda s: _set(s, ground_file="../g.csv"), SJ, "field 'ground_points'"),
    "ground file scene.json": (lambda s: _set(s, ground_file="scene.json"), SJ, "field 'ground_points'"),
    "video of no camera": (lambda s: _set(s, videos={"nope": "video/n.mp4"}), SJ, "field 'videos.nope'"),
    "video outside": (lambda s: _set(s, videos={"c0": "/etc/passwd"}), SJ, "field 'videos.c0'"),
    "class size 0": (lambda s: s.extra.update(class_sizes={"car": [0, 1.8, 1.5]}), SJ,
                     "field 'extra.class_sizes.car'"),
    "class sizes a list": (lambda s: s.extra.update(class_sizes=[4, 2, 1]), SJ, "field 'extra.class_sizes'"),
    "name not a text": (lambda s: _set(s, name=5), SJ, "field 'name'"),
    "two ground points": (lambda s: _set(s, ground_points=s.ground_points[:2]), GP,
                          "need at least 3 ground points, got 2"),
    "a ground point twice": (lambda s: _set(s, ground_points=s.ground_points[[0, 1, 2, 1]]), GP,
                             "duplicate ground point [1.0, 0.0, 0.1]"),
    "ground point nan": (lambda s: s.ground_points.__setitem__((2, 2), math.nan), GP,
                         "NaN or inf in ground point"),
    "ground point 1e7 m": (lambda s: s.ground_points.__setitem__((3, 0), 1e7), GP,
                           "is more than 1e+06 m from the origin"),
}


def files(root) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def write_by_hand(root, s: Scene) -> None:
    """scene.json and the ground points as the writer would write them, unchecked (NaN as JSON's
    NaN); the ground points only where their name stays inside ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    (root / SJ).write_text(json.dumps(s.to_dict()))
    if ".." not in s.ground_file and s.ground_file != SJ:
        g = root / s.ground_file
        g.parent.mkdir(parents=True, exist_ok=True)
        g.write_text("x,y,z\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in s.ground_points.tolist()))


def refused(fn) -> str:
    with pytest.raises(InputError) as e:
        fn()
    assert "\n" not in str(e.value), str(e.value)
    return str(e.value)


@pytest.mark.parametrize("case", list(CASES))
def test_writer_and_reader_refuse_the_same_field(tmp_path, case):
    change, name, what = CASES[case]
    s = make_scene(tmp_path / "w")
    old = files(tmp_path / "w")
    change(s)
    msg = refused(s.save)
    assert f"{tmp_path / 'w' / name}" in msg and what in msg, msg
    assert files(tmp_path / "w") == old and sorted(p.name for p in tmp_path.iterdir()) == ["w"]
    write_by_hand(tmp_path / "r", s)
    msg = refused(lambda: load_scene(tmp_path / "r"))
    assert f"{tmp_path / 'r' / name}" in msg and what in msg, msg


def test_the_reader_names_the_ground_points_line(tmp_path):
    s = make_scene(tmp_path)
    (tmp_path / GP).write_text("x,y,z\n0,0,0\n\n1,0,0.1\n0,1,0.2\n1,0,0.1\n")
    assert refused(lambda: load_scene(tmp_path)).startswith(f"{tmp_path / GP}:4: duplicate ground point")
    msg = refused(lambda: write_ground_points(tmp_path / "g.csv", s.ground_points[[0, 1, 0]]))
    assert msg.startswith(f"{tmp_path / 'g.csv'}: field 'point 1': duplicate ground point [0.0, 0.0, 0.0]")
    assert not (tmp_path / "g.csv").exists()


def test_scene_version_writer_refuses_what_load_scene_refuses(tmp_path):
    """calibrate-camera into a scene: the new scene.json is checked before its version folder
    and the swap."""
    from seg2pose.io.calib_files import write_scene_version

    s = make_scene(tmp_path)
    old = files(tmp_path)
    d = s.to_dict()
    d["cameras"][0]["width"] = 0
    msg = refused(lambda: write_scene_version(tmp_path, json.dumps(d), "{}", {"calib.json": b"{}"}, 1))
    assert msg.startswith(f"{tmp_path / SJ}: field 'cameras[c0].width': this scene would not be readable: "
                          "expected an integer in [1, 1048576], got 0"), msg
    assert files(tmp_path) == old and not (tmp_path / "calibrations").exists()
    write_scene_version(tmp_path, json.dumps(s.to_dict()), "{}", {"calib.json": b"{}"}, 1)
    assert load_scene(tmp_path).to_dict() == json.loads(json.dumps(s.to_dict()))


def test_a_scene_without_classes_holds_the_defaults_the_reader_reads(tmp_path):
    """``classes: []`` is read as the default classes; a Scene without classes held none and was
    written with none, so it read back with three."""
    s = make_scene(tmp_path)
    s = Scene(tmp_path, "t", 10.0, s.rig, s.ground_points, [])
    assert [c.name for c in s.classes] == ["pedestrian", "bicyclist", "car"]
    s.classes = []
    assert s.to_dict()["classes"] == DEFAULT_CLASSES
    s.save()
    assert load_scene(tmp_path).to_dict()["classes"] == DEFAULT_CLASSES


def test_class_sizes_and_defaults_as_read(tmp_path):
    s = make_scene(tmp_path)
    s.extra["class_sizes"] = {"car": [4, 2, 1.5]}
    d = s.to_dict()
    del d["classes"][1]["default_height"]
    write_by_hand(tmp_path / "r", s)
    (tmp_path / "r" / SJ).write_text(json.dumps(d))
    r = load_scene(tmp_path / "r")
    assert [(c.id, c.name, c.default_height) for c in r.classes] == [(1, "pedestrian", 0.8), (3, "car", 0.9)]
    assert r.class_sizes()["car"] == (4.0, 2.0, 1.5) and r.extra["class_sizes"]["car"] == [4, 2, 1.5]


# --- any scene the writer accepts, the reader loads equal; what it refuses, the reader refuses ------
safe = st.text(alphabet="abc_-0", min_size=1, max_size=4)
unsafe = st.text(alphabet="ab./ ", max_size=3)
metres = st.floats(-1e6, 1e6)
START = ["2021-06-14T08:00:00Z", "2021-06-14T10:00:00.25+02:00", "2021-06-14T08:00:00",
         "2200-01-01T00:00:00Z", "1969-12-31T23:59:59Z"]
FIELDS = ["fps", "camera", "width", "config", "class", "split", "start", "ground file", "video",
          "sizes", "ground"]


@st.composite
def scenes(draw, root) -> Scene:
    """A scene with at most one field drawn from values that may be bad (``bad``), the others
    from values the schema accepts."""
    bad = draw(st.sampled_from(["none"] * 6 + FIELDS))

    def pick(field, good, wrong):
        return wrong if bad == field else good

    cams = {}
    for i in range(draw(st.integers(1, 2))):
        name = f"{draw(pick('camera', safe, unsafe))}{i if i else ''}"
        cams[name] = Camera.look_at(name, [draw(st.floats(-50, 50)), -10.0, 5.0], [0.0, 0.0, 0.0],
                                    draw(st.floats(1.0, 1e4)),
                                    draw(pick("width", st.integers(1, 2 ** 20), st.integers(2 ** 20, 2 ** 21))),
                                    draw(st.integers(1, 480)))
    configs = {draw(pick("config", safe, unsafe)): draw(st.lists(st.sampled_from(
        [*cams, "nope"] if bad == "config" else list(cams)), min_size=1, max_size=2)) for _ in range(2)}
    ids = draw(st.lists(pick("class", st.integers(1, 65535), st.integers(0, 70000)), max_size=3,
                        unique=bad != "class"))
    classes = [ClassSpec(k, f"{draw(pick('class', safe, unsafe))}{i}",
                         draw(pick("class", st.floats(0.0, 20.0), st.floats(-1.0, 25.0))))
               for i, k in enumerate(ids)]
    first, last = draw(st.integers(0, 9)), draw(st.integers(0, 9))
    s = Scene(root=root, name=draw(st.text(max_size=5)),
              fps=draw(pick("fps", st.floats(1e-3, 1e6), st.sampled_from([0.0, -1.0, math.nan, 2e6]))),
              rig=Rig(cams, {}, "r"), ground_points=np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
              classes=classes,
              splits={"train": (first - (bad == "split"), last) if bad == "split" else tuple(sorted((first, last)))},
              start_time=draw(st.none() | st.sampled_from(START[:2] if bad != "start" else START[2:])),
              ground_file=draw(st.sampled_from([GP, "g/pts.csv"] if bad != "ground file" else ["../g.csv", SJ])),
              videos={c: "video/v.mp4" for c in draw(st.lists(st.sampled_from(
                  [*cams, "x"] if bad == "video" else list(cams)), max_size=1))},
              extra={"class_sizes": {"car": draw(pick(
                  "sizes", st.lists(st.floats(1e-3, 1000.0), min_size=3, max_size=3),
                  st.lists(st.floats(-1.0, 2000.0), min_size=2, max_size=3)))}})
    s.rig.configs = configs
    s.ground_points = np.array(draw(pick("ground", st.lists(st.tuples(metres, metres, metres), min_size=3, max_size=5,
                                                             unique=True),
                                         st.lists(st.tuples(*[metres | st.just(math.nan)] * 3), min_size=2,
                                                  max_size=4))))
    return s


@settings(FUZZ, max_examples=25)
@given(st.data())
def test_what_the_writer_accepts_the_reader_loads_equal(data):
    with folder() as d:
        s = data.draw(scenes(d / "w"))
        try:
            s.save()
        except InputError as e:
            assert "\n" not in str(e) and not (d / "w").exists()
            write_by_hand(d / "r", s)
            with pytest.raises(InputError):
                load_scene(d / "r")
            return
        r = load_scene(d / "w")
        assert r.to_dict() == json.loads(json.dumps(s.to_dict()))
        assert np.array_equal(r.ground_points, s.ground_points)
        assert r.start_time_ns == s.start_time_ns and r.class_sizes() == s.class_sizes()


def test_calibrate_camera_refuses_ground_points_new_scene_refuses(tmp_path):
    from seg2pose.io.calib_files import write_calibration

    cam = make_scene(tmp_path / "s").cameras["c0"].to_dict()
    pts = np.array([[0.0, 0, 0], [1, 0, 0]])
    msg = refused(lambda: write_calibration(tmp_path / "calib.json", [cam], {}, "", pts, {}))
    assert "need at least 3 ground points, got 2" in msg and "calib.json" not in msg, msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_restored_video_of_a_camera_the_scene_lacks_is_refused(tmp_path):
    """import-mcap's restored videos are named in scene.json: a video of a camera the scene
    lacks was written there, and load_scene then refused the restored scene."""
    from fractions import Fraction

    import av

    from s2p_review.annotated_mcap import restore_video

    make_scene(tmp_path)
    cc = av.CodecContext.create("libx264", "w")
    cc.width, cc.height, cc.pix_fmt = 64, 48, "yuv420p"
    cc.framerate, cc.time_base = Fraction(10), Fraction(1, 10)
    cc.options = {"preset": "ultrafast", "tune": "zerolatency"}
    msgs = []
    for i in range(3):
        vf = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 40 * i, np.uint8), format="bgr24")
        vf.pts = i
        msgs += [(int(p.pts) * 10 ** 8, bytes(p)) for p in cc.encode(vf)]
    msgs += [(int(p.pts) * 10 ** 8, bytes(p)) for p in cc.encode(None)]
    old = (tmp_path / SJ).read_bytes()
    msg = refused(lambda: restore_video({"c9": msgs}, tmp_path, 10.0, 0, file=tmp_path / "x.mcap"))
    assert msg.startswith(f"{tmp_path / 'x.mcap'}: the restored scene would be invalid (scene.json field "
                          "videos.c9): no camera 'c9' in the scene"), msg
    assert (tmp_path / SJ).read_bytes() == old
    assert restore_video({"c0": msgs}, tmp_path, 10.0, 0)["c0"]["frames"] == 3
    assert load_scene(tmp_path).videos == {"c0": "video/c0.mp4"}
