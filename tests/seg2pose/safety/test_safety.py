"""Traffic conflicts (seg2pose.safety): hand-computed cases (cars 4 x 1.8 m, 30 fps) and
property tests of TTC."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.safety.conflicts import ConflictOptions, analyse, format_conflicts
from seg2pose.safety.footprints import overlaps
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc

FPS = 30
CAR = (4.0, 1.8)


def make_tracks(users, fps=FPS):
    """users: list of (track id, class, frames (n,), xy (n, 2), heading (n,), size (l, w))."""
    fr, tid, cls, xy, hd, size = [], [], [], [], [], []
    for i, c, f, p, h, s in users:
        n = len(f)
        fr.append(f)
        tid.append(np.full(n, i))
        cls += [c] * n
        xy.append(p)
        hd.append(np.broadcast_to(h, (n,)))
        size.append(np.tile(s, (n, 1)))
    return Tracks(np.concatenate(fr), np.concatenate(tid), np.array(cls, object),
                  np.concatenate(xy), np.concatenate(hd), np.concatenate(size), fps)


def one(table):
    assert len(table) == 1
    return {k: v[0] for k, v in table.columns.items()}


def follower(fps=FPS):
    """Leader at 10 m/s; follower at 15 m/s from a 24 m bumper gap, closing at 5 m/s until the
    gap is 4 m at t = 4 s (frame 120), then at the leader's speed."""
    t = np.arange(0, 7, 1 / fps)
    f = np.arange(len(t))
    lead = 28.0 + 10 * t
    foll = np.where(t <= 4.0, 15 * t, 60.0 + 10 * (t - 4.0))
    z = np.zeros(len(t))
    return make_tracks([(1, "car", f, np.c_[lead, z], 0.0, CAR), (2, "car", f, np.c_[foll, z], 0.0, CAR)])


def test_follower_sudden_slowing():
    """The follower's speed drops from 15 to 10 m/s at once at frame 120: the smoother spreads
    the change over its narrowest window (5 frames on an exact track), so the last frame it
    still sees 15 m/s is 118: min TTC = (4 + 2 / 30 * 5) m / 5 m/s = 0.867 s there."""
    r = one(analyse(follower(), ConflictOptions(workers=1)))
    assert r["min_ttc_s"] == pytest.approx(4.0 / 5 + 2.0 / 30, abs=1e-6)
    assert r["min_ttc_frame"] == 118
    assert r["type"] == "rear-end" and r["conflict"] == 1
    assert r["pet_s"] == pytest.approx(0.4, abs=1e-6)  # the follower reaches the leader's spot 4 m / 10 m/s later
    assert r["max_s_mps"] == pytest.approx(15.0, abs=1e-6)


def crossing():
    """Car 1 along +x, car 2 along +y, both 10 m/s, through the origin at t = 3 s and 5 s."""
    t = np.arange(0, 8, 1 / FPS)
    f = np.arange(len(t))
    z = np.zeros(len(t))
    return make_tracks([(1, "car", f, np.c_[10 * (t - 3), z], 0.0, CAR),
                        (2, "car", f, np.c_[z, 10 * (t - 5)], np.pi / 2, CAR)])


def test_right_angle_crossing_pet():
    """The first one's rear leaves the 1.8 x 1.8 m shared square at 3.29 s, the second one's
    front enters it at 4.71 s: PET 1.42 s; no collision course, so no TTC."""
    table = analyse(crossing(), ConflictOptions())
    r = one(table)
    assert r["pet_s"] == pytest.approx(1.42, abs=1e-6)
    assert table.pets.t_exit[0] == pytest.approx(3.29, abs=1e-6)
    assert table.pets.t_enter[0] == pytest.approx(4.71, abs=1e-6)
    assert (r["pet_first_track"], r["pet_exit_frame"], r["pet_enter_frame"]) == (1, 98, 142)
    assert np.isnan(r["min_ttc_s"])
    assert r["type"] == "crossing" and r["angle_deg"] == pytest.approx(90, abs=1e-6)


def turning_car_and_pedestrian(fps=FPS):
    """A car turns left (quarter circle, radius 10 m, 6 m/s) into a road along +y; a pedestrian
    crosses that road at y = 15 m (1.4 m/s along +x), through the car's path 2 s before it (its centre line; with the
    footprints: the pedestrian clears the lane 0.76 s before the car's front reaches it)."""
    v, R = 6.0, 10.0
    t = np.arange(0, 12, 1 / fps)
    s = v * t - 20.0  # arc length from the turn's start
    arc = np.pi / 2 * R
    a = np.clip(s, 0, arc) / R
    x = np.where(s < 0, s, np.where(s <= arc, R * np.sin(a), R))
    y = np.where(s < 0, 0.0, np.where(s <= arc, R - R * np.cos(a), R + (s - arc)))
    h = np.where(s < 0, 0.0, np.where(s <= arc, a, np.pi / 2))
    t_car = (20.0 + arc + 5.0) / v  # the car's centre at y = 15
    xp = 10.0 + 1.4 * (t - (t_car - 2.0))
    f = np.arange(len(t))
    keep = (xp > 2) & (xp < 18)
    return make_tracks([(3, "car", f, np.c_[x, y], h, CAR),
                        (4, "pedestrian", f[keep], np.c_[xp[keep], np.full(keep.sum(), 15.0)],
                         0.0, (0.6, 0.6))], fps), (x, y, h, xp, t)


def brute_force_pet(step=120):
    """PET by brute force at ``step`` fps (+-1/240 s): the smallest time between two moments at
    which the footprints overlap (searched from 3 s before the car's centre reaches y = 15 m)."""
    tr, _ = turning_car_and_pedestrian(fps=step)
    late = tr.t > (20.0 + np.pi / 2 * 10.0 + 5.0) / 6.0 - 3.0
    a = np.flatnonzero((tr.track_id == 3) & late)
    b = np.flatnonzero((tr.track_id == 4) & late)
    ia, ib = np.meshgrid(a, b, indexing="ij")
    ia, ib = ia.ravel(), ib.ravel()
    ok = np.abs(tr.t[ia] - tr.t[ib]) < 3
    ia, ib = ia[ok], ib[ok]
    hit = overlaps(tr.xy[ia], tr.heading[ia], tr.size[ia], tr.xy[ib], tr.heading[ib], tr.size[ib])
    return float(np.abs(tr.t[ia[hit]] - tr.t[ib[hit]]).min())


def test_pedestrian_in_front_of_turning_car():
    tr, _ = turning_car_and_pedestrian()
    r = one(analyse(tr, ConflictOptions()))
    assert r["type"] == "pedestrian" and r["conflict"] == 1
    assert r["pet_first_track"] == 4  # the pedestrian was there first
    assert r["pet_s"] == pytest.approx(brute_force_pet(), abs=0.01)
    # the car's straight part: pedestrian (0.3 m half width) clears the car's half width 0.9 m
    # at 1.4 m/s; the car's front (2 m ahead of its centre) reaches the pedestrian's edge at 6 m/s
    assert r["pet_s"] == pytest.approx(2.0 - (0.9 + 0.3) / 1.4 - (2.0 + 0.3) / 6.0, abs=0.01)


def test_parallel_lanes_no_conflict():
    """Side by side in neighbouring lanes (3.5 m apart), one 2 m ahead, same speed."""
    t = np.arange(0, 5, 1 / FPS)
    f = np.arange(len(t))
    tr = make_tracks([(1, "car", f, np.c_[10 * t, np.zeros(len(t))], 0.0, CAR),
                      (2, "car", f, np.c_[10 * t + 2, np.full(len(t), 3.5)], 0.0, CAR)])
    assert len(analyse(tr, ConflictOptions())) == 0
    r = one(analyse(tr, ConflictOptions(all_pairs=True)))  # an encounter, no indicator
    assert r["conflict"] == 0 and np.isnan(r["min_ttc_s"]) and np.isnan(r["pet_s"])
    assert r["min_distance_m"] == pytest.approx(3.5 - 1.8)  # side by side: the gap between them


def test_stationary_road_user_no_division_by_zero():
    """A parked car; a pedestrian walks towards it and stops 1 m short; a second parked car
    beside the first. No warnings (no 0/0), TTC of the walker finite, none between the parked."""
    t = np.arange(0, 6, 1 / FPS)
    f = np.arange(len(t))
    n = len(t)
    xp = np.minimum(-10 + 1.5 * t, -3.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tr = make_tracks([(1, "car", f, np.zeros((n, 2)), 0.0, CAR),
                          (2, "car", f, np.c_[np.zeros(n), np.full(n, 2.5)], 0.0, CAR),
                          (3, "pedestrian", f, np.c_[xp, np.zeros(n)], 0.0, (0.6, 0.6))])
        table = analyse(tr, ConflictOptions(all_pairs=True))
        text = format_conflicts(table, FPS)
    c = table.columns
    rows = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(c["track_a"], c["track_b"]))}
    assert np.isnan(c["min_ttc_s"][rows[(1, 2)]])
    walker = rows[(1, 3)]
    assert 0 < c["min_ttc_s"][walker] < 2.0  # 1.5 m/s, 0.9 + ... m short of the bumper
    assert "nan" not in text and "inf" not in text


# ----------------------------------------------------------------------------------------------
# properties of TTC

coord = st.floats(-50, 50)
speed = st.floats(-20, 20)
angle = st.floats(-np.pi, np.pi)
length = st.floats(0.3, 12)


@st.composite
def road_user(draw):
    return (np.array([[draw(coord), draw(coord)]]), np.array([draw(angle)]),
            np.array([[draw(length), draw(st.floats(0.3, 3))]]), np.array([[draw(speed), draw(speed)]]))


def same(x, y):
    return (np.isnan(x) and np.isnan(y)) or abs(x - y) <= 1e-6 * max(1.0, abs(x))


@settings(max_examples=100, deadline=None)
@given(road_user(), road_user(), coord, coord, angle)
def test_ttc_symmetric_invariant_nonnegative(a, b, dx, dy, rot):
    x = ttc(*a[:3], a[3], *b[:3], b[3], horizon_s=30.0)[0]
    assert np.isnan(x) or x >= 0
    assert same(x, ttc(*b[:3], b[3], *a[:3], a[3], horizon_s=30.0)[0])
    # moving the origin
    shift = np.array([[dx, dy]])
    assert same(x, ttc(a[0] + shift, a[1], a[2], a[3], b[0] + shift, b[1], b[2], b[3],
                       horizon_s=30.0)[0]) or _grazing(a, b)
    # rotating the world
    c, s = np.cos(rot), np.sin(rot)
    Rm = np.array([[c, -s], [s, c]])

    def rot_of(u):
        return (u[0] @ Rm.T, u[1] + rot, u[2], u[3] @ Rm.T)

    ra, rb = rot_of(a), rot_of(b)
    assert same(x, ttc(*ra[:3], ra[3], *rb[:3], rb[3], horizon_s=30.0)[0]) or _grazing(a, b)


def _grazing(a, b) -> bool:
    """A course that only just touches (or just reaches the horizon): rounding may tip it."""
    xs = [ttc(a[0] + e, a[1], a[2], a[3], b[0], b[1], b[2], b[3], horizon_s=30.0)[0]
          for e in (np.array([[1e-6, 0]]), np.array([[0, 1e-6]]), np.array([[-1e-6, 0]]),
                    np.array([[0, -1e-6]]))]
    return len({bool(np.isnan(v)) for v in xs}) > 1 or any(np.isfinite(v) and v > 29.99 for v in xs)


def test_safety_imports_only_core_and_io():
    """seg2pose.safety runs on tracks: within seg2pose it may use errors, say, io and itself."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[3] / "seg2pose" / "safety"
    assert sorted(root.glob("*.py")), root
    # core.validate was io.validate (the file checks every reader uses)
    ok = ("seg2pose.core.errors", "seg2pose.core.say", "seg2pose.core.validate", "seg2pose.io",
          "seg2pose.safety")
    bad = []
    for p in sorted(root.glob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{p.name}: {n}" for n in names if n.startswith("seg2pose")
                    and not any(n == o or n.startswith(o + ".") for o in ok)]
    assert bad == []


@settings(max_examples=100, deadline=None)
@given(road_user(), road_user())
def test_static_overlap_agrees_with_the_interval(a, b):
    """``overlaps`` (the static test) says what ``overlap_interval`` says at time 0."""
    from seg2pose.safety.footprints import overlap_interval

    enter, leave = overlap_interval(*a[:3], *b[:3], np.zeros((1, 2)))
    assert overlaps(*a[:3], *b[:3])[0] == bool(enter[0] <= leave[0])


def test_interval_heading_noise():
    """Perturbing headings (--heading90) widens the PET interval of the right-angle crossing
    (the footprints turn); with a heading error of 0 the draws are those without it."""
    from seg2pose.safety.intervals import IntervalOptions, conflict_intervals

    tr = crossing()
    table = analyse(tr, ConflictOptions())
    r90 = np.full(len(tr), 0.3)
    io_ = IntervalOptions(draws=100)
    plain = conflict_intervals(tr, table, ConflictOptions(), io_, r90=r90)
    zero = conflict_intervals(tr, table, ConflictOptions(), io_, r90=r90, heading90=np.zeros(len(tr)))
    turned = conflict_intervals(tr, table, ConflictOptions(), io_, r90=r90,
                                heading90=np.full(len(tr), np.radians(30)))
    for k in plain:
        np.testing.assert_array_equal(zero[k], plain[k])
    assert plain["pet_lo_s"][0] <= 1.42 <= plain["pet_hi_s"][0]
    assert (turned["pet_hi_s"][0] - turned["pet_lo_s"][0]) > (plain["pet_hi_s"][0] - plain["pet_lo_s"][0])


def test_interval_width_follows_each_poses_r90():
    """Per-pose error radii (poses.csv's r90_m): the PET interval of the right-angle crossing
    widens in proportion to the r90 of the one road user that has an error. By hand: with car 2
    exact and car 1's slow error e (sigma = r90 / 2.146 per axis; the straight clean track has
    no fast part), car 1 leaves the shared square e_x / 10 s early and car 2 meets car 1's
    path e_y / 10 s early, so PET deviates by (e_y - e_x) / 10 m/s, standard deviation
    sqrt(2) sigma / 10; the 90 % interval, widened ``spread`` times, is
    2 x 1.645 x spread x sqrt(2) r90 / 2.146 / 10 wide: 0.0238 s for r90 = 0.05 m and
    spread 2.2. The same unit draws (one seed) with twice the radius give twice the width
    (small errors: at r90 = 0.2 m the footprint's heading from the noisy motion adds 8 %)."""
    from seg2pose.safety.intervals import IntervalOptions, conflict_intervals

    tr = crossing()
    table = analyse(tr, ConflictOptions())
    io_ = IntervalOptions(draws=400, spread=(1.0, 1.0, 2.2))
    one_m = tr.track_id == 1
    widths = []
    for r in (0.05, 0.1):
        iv = conflict_intervals(tr, table, ConflictOptions(), io_, r90=np.where(one_m, r, 0.0))
        assert iv["pet_lo_s"][0] <= 1.42 <= iv["pet_hi_s"][0]
        widths.append(iv["pet_hi_s"][0] - iv["pet_lo_s"][0])
    hand = 2 * 1.6449 * 2.2 * np.sqrt(2) * 0.05 / np.sqrt(2 * np.log(10)) / 10
    assert widths[0] == pytest.approx(hand, rel=0.1)
    assert widths[1] / widths[0] == pytest.approx(2.0, rel=0.03)
