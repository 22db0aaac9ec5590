"""The video's look (synth/look.py, synth/video.py): clouds that change the light, textured
bodies, and the flat look left byte for byte as it was."""

from __future__ import annotations

import hashlib
import json

import cv2
import numpy as np
import pytest
from video_fixtures import single_threaded_opencv

from seg2pose.core.errors import InputError
from seg2pose.synth.look import (
    PATCHES,
    PLAIN,
    STRIPES,
    SUN_MIN,
    BodyTextures,
    Cloud,
    draw_clouds,
    draw_textures,
    exposure_gain,
    ground_light,
    look_named,
    sun_strength,
    texture_values,
)
from seg2pose.synth.rig import make_device
from seg2pose.synth.shapes import hexa
from seg2pose.synth.video import background, render_frame
from seg2pose.synth.world import World

# OpenCV's worker pool, once started here, hangs synth's forked workers in later tests
opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)


@pytest.fixture(scope="module")
def cam():
    return make_device().cameras["c1"]


def box_world(xyz, kind=0) -> World:
    """One frame, one single-part road user (a 4 x 1.8 x 1.5 m box) at ``xyz``, or none."""
    n = 0 if xyz is None else 1
    box = hexa(-2.0, 2.0, -0.9, 0.9, 0.0, 1.5)
    return World(frame=np.zeros(n, np.int64), track=np.arange(1, n + 1), cls=np.full(n, 2, np.int8),
                 xyz=np.asarray(xyz if n else np.zeros((0, 3)), float).reshape(n, 3),
                 heading=np.zeros(n), phase=np.zeros(n), frame_ptr=np.array([0, n]),
                 verts=np.stack([box] * n) if n else np.zeros((0, 8, 3)), swing=np.zeros(n),
                 kind=np.full(n, kind, np.int8), part_ptr=np.arange(n + 1),
                 size=np.array([[4.0, 1.8, 1.5]] * n).reshape(n, 3),
                 colour=np.array([[200, 30, 30]] * n, np.uint8).reshape(n, 3))  # unlike the ground


def test_flat_look_is_the_renderer_as_it_was():
    """The small preset's frames, hashed with the renderer before the look existed."""
    from seg2pose.synth.generate import DT, PRESETS
    from seg2pose.synth.traffic import TrafficConfig, simulate
    from seg2pose.synth.world import build_world

    p = PRESETS["small"]
    visits = simulate(TrafficConfig(population=dict(p["population"]),
                                    mean_pause_s=dict(p["mean_pause_s"])), 40, DT, 7)
    world = build_world(visits, 40, 7)
    cam = make_device().cameras["c1"]
    bg = background(cam)
    h = hashlib.sha256()
    for f in (0, 17, 39):
        h.update(render_frame(cam, world, f, bg).tobytes())
    assert h.hexdigest() == "c29bb8db62db8cbd11794daba12baf1400b879782f7d078eaed29d183f581d92"


def test_sun_strength_of_one_and_two_clouds():
    c = Cloud(t0=10.0, half=4.0, depth=0.5)
    s = sun_strength([c], np.array([0.0, 6.0, 8.0, 10.0, 12.0, 14.0, 30.0]))
    # raised cosine: 1 - 0.5 * (1 + cos(pi x)) / 2 at x = (t - 10) / 4
    np.testing.assert_allclose(s, [1.0, 1.0, 0.75, 0.5, 0.75, 1.0, 1.0])
    two = sun_strength([c, Cloud(10.0, 4.0, 0.6)], np.array([10.0, 12.0]))
    np.testing.assert_allclose(two, [SUN_MIN, 0.75 * 0.7])  # 0.5 * 0.4 = 0.2: the floor; 0.75 * 0.7


def test_clouds_pass_over_a_benchmark_scene():
    dt, n = 0.075, 3 * 980
    for seed in (0, 100, 101, 102):
        clouds = draw_clouds(seed, n * dt)
        assert clouds == draw_clouds(seed, n * dt)  # deterministic per seed
        assert all(0.3 <= c.depth <= 1 - SUN_MIN and 4.0 <= c.half <= 12.0 for c in clouds)
        s = sun_strength(clouds, np.arange(n) * dt)
        assert s.min() < 0.7 and (s == 1.0).mean() > 0.3  # clouds dim the sun, and pass
        assert np.abs(np.diff(s)).max() < 0.03  # the light changes over seconds, not at a frame
    assert draw_clouds(0, 200.0) != draw_clouds(1, 200.0)


def test_light_on_the_ground_and_in_a_shadow(cam):
    bg = background(cam)
    # no road user: the ground dims with the sun, half made up by the exposure (sqrt)
    s = 0.2
    assert ground_light(s) == pytest.approx(0.64) and exposure_gain(s) == pytest.approx(1.25)
    empty = render_frame(cam, box_world(None), 0, bg, sun=s)
    np.testing.assert_allclose(empty.astype(float), np.round(bg * 0.8), atol=1)
    # a road user's shadow keeps the skylight: 0.55 of full sun, 0.55 * 1.25 under the cloud
    w = box_world([-8.0, 5.0, 0.0])  # its shadow in view beside it
    full, dim = render_frame(cam, w, 0, bg), render_frame(cam, w, 0, bg, sun=s)
    ref = np.maximum(bg.astype(float), 1)
    shade = np.all(np.abs(full / ref - 0.55) < 0.03, axis=2) & (bg.min(axis=2) > 40)
    assert shade.sum() > 500
    np.testing.assert_allclose(dim[shade] / ref[shade], 0.6875, atol=0.02)
    # the sunlit ground around it: 0.8
    lit = (full == bg).all(axis=2)
    np.testing.assert_allclose(dim[lit].mean() / bg[lit].mean(), 0.8, atol=0.01)


def test_texture_values():
    tex = BodyTextures(kind=np.array([PLAIN, STRIPES, PATCHES], np.int8), amp=np.array([0.0, 20.0, 30.0]),
                       scale=np.array([0.3, 0.25, 0.5]), offset=np.zeros((3, 2)))
    y = np.linspace(-1, 1, 41)
    x = np.zeros_like(y)
    one = np.ones(41, int)
    assert not texture_values(tex, one, x, y).any()  # plain
    st = texture_values(tex, 2 * one, x, y)
    np.testing.assert_allclose(st, 20 * np.sin(2 * np.pi * y / 0.25), atol=1e-9)
    np.testing.assert_allclose(texture_values(tex, 2 * one, x + 0.7, y + 0.25), st, atol=1e-9)
    # patches: one value per 0.5 m cell, within the amplitude, not all the same
    xs = np.array([0.01, 0.2, 0.49, 0.51, 1.2, 2.7])
    pv = texture_values(tex, 3 * np.ones(6, int), xs, np.full(6, 0.1))
    assert pv[0] == pv[1] == pv[2] and np.abs(pv).max() <= 30 and len(np.unique(pv)) > 2


def test_textures_per_road_user():
    cls = np.repeat(np.array([0, 1, 2], np.int8), 3000)
    a, b = draw_textures(cls, 4), draw_textures(cls, 4)
    for f in ("kind", "amp", "scale", "offset"):  # the same in every camera (drawn per seed)
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert not np.array_equal(a.offset, draw_textures(cls, 5).offset)
    cars = a.kind[cls == 2]
    assert abs((cars == PLAIN).mean() - 0.40) < 0.03 and abs((cars == PATCHES).mean() - 0.45) < 0.03
    assert (a.amp[a.kind == PLAIN] == 0).all() and (a.amp[a.kind != PLAIN] >= 12).all()
    assert ((a.scale[a.kind == STRIPES] >= 0.08) & (a.scale[a.kind == STRIPES] <= 0.35)).all()


def test_pattern_sticks_to_the_body(cam):
    """A patterned box moved along the ground: its pixels keep their pattern relative to the
    box (the same offsets from the plain rendering at the same place on the body)."""
    bg = background(cam)
    tex = BodyTextures(kind=np.array([PATCHES], np.int8), amp=np.array([30.0]),
                       scale=np.array([0.4]), offset=np.zeros((1, 2)))
    w1, w2 = box_world([3.0, 2.0, 0.0]), box_world([3.0, 2.0, 0.0])
    plain = render_frame(cam, w1, 0, bg).astype(int)
    d1 = render_frame(cam, w1, 0, bg, textures=tex).astype(int) - plain
    assert (np.abs(d1).sum(axis=2) > 0).sum() > 2000  # the body is patterned
    w2.xyz[0, :2] += cam.R[0, :2] / np.linalg.norm(cam.R[0, :2]) * 0.5  # 0.5 m to the image's right
    plain2 = render_frame(cam, w2, 0, bg).astype(int)
    d2 = render_frame(cam, w2, 0, bg, textures=tex).astype(int) - plain2
    (u1, v1), (u2, v2) = [np.argwhere(np.abs(d).sum(axis=2) > 0).mean(axis=0)[::-1] for d in (d1, d2)]
    du, dv = int(round(u2 - u1)), int(round(v2 - v1))
    assert du > 5  # it moved
    inner = np.abs(d1).sum(axis=2) > 0
    inner &= np.roll(np.roll(np.abs(d2).sum(axis=2) > 0, -dv, 0), -du, 1)
    moved = np.roll(np.roll(d2, -dv, 0), -du, 1)
    same = (np.abs(moved[inner] - d1[inner]) <= 2).all(axis=1).mean()
    assert same > 0.8, same


def test_scenes_look(tmp_path):
    from seg2pose.synth.generate import SynthOptions, generate_scene

    kw = dict(preset="wide", frames=3, seed=3, progress=False, video=True, workers=1,
              population={"car": 3, "pedestrian": 3, "bicyclist": 1})
    rich = generate_scene(tmp_path / "r", SynthOptions(**kw))
    flat = generate_scene(tmp_path / "f", SynthOptions(**kw, look="flat"))
    gr = json.loads((rich / "scene.json").read_text())["extra"]["generator"]
    gf = json.loads((flat / "scene.json").read_text())["extra"]["generator"]
    assert gr["look"] == "rich" and "look" not in gf
    for sub in ("masks", "gt"):  # the look changes the video only
        for f in (rich / sub).iterdir():
            assert f.read_bytes() == (flat / sub / f.name).read_bytes(), f
    a, b = cv2.VideoCapture(str(rich / "video" / "c1.mp4")), cv2.VideoCapture(str(flat / "video" / "c1.mp4"))
    differs = 0
    while True:
        ok_a, ia = a.read()
        ok_b, ib = b.read()
        assert ok_a == ok_b
        if not ok_a:
            break
        differs += int(np.abs(ia.astype(int) - ib.astype(int)).max() > 10)
    assert differs > 0
    with pytest.raises(InputError, match="unknown look 'glossy'"):
        look_named("glossy")
