"""Headings along the motion (annotate/headings.py): keyframes placed without a heading follow
the direction of motion from their neighbours until the annotator sets them."""

import math

import numpy as np
import pytest
from review_fixtures import make_scene

from annotate import Project
from annotate.headings import AUTO, motion_headings


@pytest.fixture
def project(tmp_path):
    p = Project.open(make_scene(tmp_path / "scene", n_frames=60))
    yield p
    p.close()


def _heading(p, tid, frame):
    tab = p.track_poses(tid)
    return float(tab.heading[np.flatnonzero(tab.frame == frame)[0]])


def test_issue_reproduction_first_keyframe_follows_the_motion(project):
    """Issue 22's reproduction: keyframes at (0, 0) frame 10 and (0, 10) frame 35, no heading:
    the motion is along +y (pi/2) at both keyframes and everywhere between."""
    p = project
    t = p.create_track("car").track
    p.set_keyframe(t, 10, x=0, y=0)
    p.set_keyframe(t, 35, x=0, y=10)
    for f in (10, 20, 35):
        assert _heading(p, t, f) == pytest.approx(math.pi / 2, abs=1e-9), f
    assert all(AUTO in k.flags for k in p.track(t).keyframes.values())
    # the interpolation runs straight along x = 0 (it swung sideways with heading 0 at frame 10)
    np.testing.assert_allclose(p.track_poses(t).xyz[:, 0], 0.0, atol=1e-9)


def test_the_same_with_place_from_pixel(project):
    p = project
    cam = p.scene.cameras["c1"]
    t = p.create_track("car").track
    pts = np.array([[0.0, -3.0, 0.0], [4.0, 1.0, 0.0]])
    pts[:, 2] = p.scene.ground.height(pts[:, :2])
    uv, _, _ = cam.project_points(pts)
    p.place_from_pixel(t, 10, "c1", uv[0])
    p.place_from_pixel(t, 30, "c1", uv[1])
    k = p.track(t).keyframes
    expect = math.atan2(k[30].y - k[10].y, k[30].x - k[10].x)
    assert expect == pytest.approx(math.pi / 4, abs=0.02)  # the clicks met the ground there
    assert k[10].heading == pytest.approx(expect, abs=1e-9)
    assert k[30].heading == pytest.approx(expect, abs=1e-9)


def test_auto_headings_follow_their_neighbours_and_set_ones_stay(project):
    p = project
    t = p.create_track("car").track
    p.set_keyframe(t, 0, 0.0, 0.0)
    p.set_keyframe(t, 20, 10.0, 0.0)
    p.set_keyframe(t, 40, 10.0, 10.0)
    k = p.track(t).keyframes
    # middle: the chord from its previous to its next keyframe (45 deg); ends: their one chord
    assert [k[f].heading for f in (0, 20, 40)] == pytest.approx([0.0, math.pi / 4, math.pi / 2])
    p.move_keyframe(t, 40, 20.0, 0.0)          # a neighbour moves: the others follow
    assert [p.track(t).keyframes[f].heading for f in (0, 20, 40)] == pytest.approx([0, 0, 0])
    p.rotate(t, 20, 10.0)                      # the annotator sets frame 20's heading
    assert AUTO not in p.track(t).keyframes[20].flags
    p.move_keyframe(t, 0, 0.0, -10.0)
    assert p.track(t).keyframes[20].heading == pytest.approx(math.radians(10))
    assert p.track(t).keyframes[0].heading == pytest.approx(math.pi / 4)  # towards frame 20
    # a repeated click (no heading) on the set keyframe keeps its heading
    p.set_keyframe(t, 20, 10.5, 0.0)
    assert p.track(t).keyframes[20].heading == pytest.approx(math.radians(10))
    # undo takes back the edit and its heading updates as one step; the journal replays them
    p.undo()
    assert p.track(t).keyframes[20].x == 10.0
    state = {f: tuple(v) for f, v in p.track(t).keyframes.items()}
    with Project.open(p.scene, read_only=True) as q:
        assert {f: tuple(v) for f, v in q.track(t).keyframes.items()} == state


def test_standing_still_keeps_the_last_heading():
    xy = np.array([[0.0, 0.0], [5.0, 5.0], [5.05, 5.0], [5.1, 5.0]])
    h = motion_headings(xy, np.zeros(4), np.array([True, True, True, True]))
    assert h[0] == pytest.approx(math.pi / 4)
    # frame 2's neighbours are 0.1 m apart: standing still, it keeps frame 1's heading
    assert h[2] == pytest.approx(h[1])
    assert h[3] == pytest.approx(h[2])
    # a lone keyframe keeps what it has
    assert motion_headings(xy[:1], np.array([1.0]), np.array([True]))[0] == 1.0
