"""Fragments of one road user joined into one track (seg2pose.video.fragments): a car that
background subtraction cut into two or three pieces moving as one becomes one track with the
union of its masks; two pedestrians side by side, pieces that do not move rigidly, tracks that
never touch and pieces seen too briefly stay apart."""

import numpy as np
import pytest
from video_fixtures import upright_box

from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.scene import ClassSpec
from seg2pose.structures.masks import decode, encode
from seg2pose.video.classify import size_rules
from seg2pose.video.fragments import find_joins, join_fragments
from seg2pose.video.track import TrackConfig

H, W, FPS = 720, 1280, 10.0
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]
RULES = size_rules(CLASSES, {})


def setup():
    g = [(x, y, 0.0) for x in range(-30, 31, 10) for y in range(-10, 61, 10)]
    cam = Camera.look_at("c0", np.array([0.0, -12.0, 9.0]), np.array([0.0, 15.0, 0.0]), 900.0, W, H)
    return cam, GroundSurface(np.array(g, float))


def write(path, rows):
    """rows: (frame, track id, mask) -> a MOTS file."""
    f, t, m = zip(*rows)
    write_mots(path, MaskTable(np.array(f), np.array(t), np.zeros(len(f), int), H, W,
                               [encode(x) for x in m]))


# a dark car whose body reads as road: only some parts stand out; parts as (x0, x1, y0, y1)
# shares of the car's box. TWO: a lower front corner (wheel) and a band along the rear;
# THREE: the lower front and rear halves and the upper middle
TWO = [(0.0, 0.3, 0.55, 1.0), (0.31, 1.0, 0.1, 0.55)]
THREE = [(0.0, 0.45, 0.6, 1.0), (0.46, 1.0, 0.6, 1.0), (0.2, 0.8, 0.0, 0.59)]


def car_in_pieces(cam, n=30, parts=TWO, wobble=0.0):
    """A car (4.5 x 2.0 m as the camera sees it) driving across, cut into ``parts``, one track
    each (ids 1, 2, ...); with ``wobble`` the second part moves back and forth by that share
    of the car's width (not rigid)."""
    rows = []
    for f in range(n):
        x0, y0, x1, y1 = upright_box(cam, (-6.0 + 0.4 * f, 18.0), 4.5, 2.0)
        for k, (a, b, c, d) in enumerate(parts):
            dx = wobble * np.sin(1.7 * f) if k == 1 else 0.0
            m = np.zeros((H, W), np.uint8)
            m[int(y0 + c * (y1 - y0)):int(y0 + d * (y1 - y0)),
              int(x0 + (a + dx) * (x1 - x0)):int(x0 + (b + dx) * (x1 - x0))] = 1
            rows.append((f, k + 1, m))
    return rows


def test_a_car_in_two_pieces_becomes_one_track_with_the_union_of_its_masks(tmp_path):
    cam, ground = setup()
    rows = car_in_pieces(cam)
    write(tmp_path / "m.txt", rows)
    joins = join_fragments(tmp_path / "m.txt", tmp_path / "j.txt", cam, ground, RULES, FPS,
                           log=lambda s: None)
    assert len(joins) == 1 and set(joins[0]) == {1, 2}
    out = read_mots(tmp_path / "j.txt")
    assert len(out) == 30 and len(set(out.track_id.tolist())) == 1
    for f in (0, 17, 29):
        want = rows[2 * f][2] | rows[2 * f + 1][2]
        got = decode(out.rles[int(np.flatnonzero(out.frame == f)[0])], H, W)
        assert np.array_equal(got.astype(bool), want.astype(bool))


def test_three_pieces_are_joined_in_two_steps_and_the_longer_track_keeps_its_id():
    cam, ground = setup()
    rows = car_in_pieces(cam, parts=THREE)
    rows = [r for r in rows if not (r[1] == 2 and r[0] < 4)]        # piece 2 seen from frame 4
    f, t, m = zip(*rows)
    box = np.array([[*np.argwhere(x.T)[0], *(np.argwhere(x.T)[-1] + 1)] for x in m], float)
    new_id, into, joins = find_joins(np.array(f), np.array(t), box, H, W, cam, ground, RULES,
                                     TrackConfig(), FPS)
    assert len(joins) == 2
    assert len(set(new_id.tolist())) == 1 and new_id[0] in (1, 3)      # not 2: the shortest
    assert (into == np.arange(len(into))).sum() == 30                   # one mask per frame
    assert all(f[i] == f[into[i]] for i in range(len(f)))              # merged within a frame


def test_two_pedestrians_side_by_side_stay_apart(tmp_path):
    """They touch and walk in step, but each fits the pedestrian class better than both
    together fit any class."""
    cam, ground = setup()
    rows = []
    for f in range(30):
        for k, dx in ((1, 0.0), (2, 0.62)):
            x0, y0, x1, y1 = upright_box(cam, (-3.0 + 0.13 * f + dx, 12.0), 0.6, 1.75)
            m = np.zeros((H, W), np.uint8)
            m[y0:y1, x0:x1] = 1
            rows.append((f, k, m))
    write(tmp_path / "m.txt", rows)
    assert join_fragments(tmp_path / "m.txt", tmp_path / "j.txt", cam, ground, RULES, FPS,
                          log=lambda s: None) == []
    assert sorted(set(read_mots(tmp_path / "j.txt").track_id.tolist())) == [1, 2]


@pytest.mark.parametrize("case", ["not rigid", "too brief", "apart", "off"])
def test_pieces_that_fail_a_test_stay_apart(tmp_path, case):
    cam, ground = setup()
    cfg = TrackConfig()
    if case == "not rigid":
        rows = car_in_pieces(cam, wobble=0.25)
    elif case == "too brief":
        rows = car_in_pieces(cam, n=8)                  # 0.8 s < join_min_s
    elif case == "apart":
        rows = [(f, k, m) for f, k, m in car_in_pieces(cam)]
        rows = [(f, k, np.roll(m, 40 * (k - 1), axis=1)) for f, k, m in rows]   # 40 px apart
    else:
        rows = car_in_pieces(cam)
        cfg = TrackConfig(join_gain=0.0)
    write(tmp_path / "m.txt", rows)
    assert join_fragments(tmp_path / "m.txt", tmp_path / "j.txt", cam, ground, RULES, FPS, cfg,
                          log=lambda s: None) == []
    a, b = read_mots(tmp_path / "m.txt"), read_mots(tmp_path / "j.txt")
    assert np.array_equal(a.track_id, b.track_id) and a.rles == b.rles
