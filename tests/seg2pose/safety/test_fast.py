"""The fast paths of seg2pose.safety against the plain computations they replace: the same
answers (bit for bit where the arithmetic is the same; to rounding where a method changed:
the velocity fits), and known answers (constant velocity, PET by brute force)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.safety import encounters
from seg2pose.safety.conflicts import ConflictOptions, RowData, analyse, pair_frames
from seg2pose.safety.encounters import class_rows, frame_pairs, near_pairs
from seg2pose.safety.footprints import Footprints, overlap_interval, overlaps
from seg2pose.safety.kinematics import _fit_rows, derivative, motion, segments
from seg2pose.safety.pet import PetOptions, overlapping_rows, pet
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc, ttc_rows
from tests.seg2pose.safety.test_safety import FPS, road_user
from tests.seg2pose.safety.test_stream import traffic


def gappy_tracks(seed: int) -> Tracks:
    """Tracks of random lengths (1-40 frames) with dropped frames (gaps), at positions far
    from the origin (late in a projected map), one track a single row."""
    rng = np.random.default_rng(seed)
    fr, tid, xy = [], [], []
    for i in range(12):
        n = int(rng.integers(1, 40)) if i else 1
        f = np.sort(rng.choice(np.arange(1000, 1000 + 3 * n + 5), n, replace=False))
        if rng.random() < 0.5:
            f = 1000 + np.arange(n)  # no gap
        fr.append(f)
        tid.append(np.full(n, i))
        xy.append(np.array([5e4, -3e4]) + np.cumsum(rng.normal(0, 0.5, (n, 2)), axis=0))
    n = sum(len(f) for f in fr)
    return Tracks(np.concatenate(fr), np.concatenate(tid), np.array(["car"] * n, object),
                  np.concatenate(xy), np.full(n, np.nan), np.tile([4.0, 1.8], (n, 1)), FPS)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n,order", [(3, 1), (5, 1), (31, 1), (5, 2), (9, 2)])
def test_derivative_by_correlation_equals_the_fit_per_row(seed, n, order):
    """Where the window's frames are consecutive the local quadratic's derivative is a fixed
    weighting of the values; elsewhere (segment ends) each row's own fit. Both agree with the
    fit of every row from its own times (``_fit_rows`` at all rows) to rounding."""
    tr = gappy_tracks(seed)
    st_, en = segments(tr)
    nn = np.full(len(tr), n)
    fast = derivative(tr, tr.xy, nn, order)
    rows = np.arange(len(tr))
    plain = _fit_rows(tr, tr.xy, nn, order, rows, st_, en)
    np.testing.assert_allclose(fast, plain, rtol=0, atol=1e-6)


def test_derivative_reproduces_a_constant_acceleration():
    """Positions of a constant acceleration (1.5, -2) m/s^2 from (3, -4) m/s, some frames
    missing (segments): every row of a segment of 3 frames or more gets the exact velocity
    and acceleration (a quadratic fits them exactly, centred or shifted at the ends)."""
    f = np.r_[np.arange(0, 50), np.arange(53, 90)]
    t = f / FPS
    xy = np.c_[1e3 + 3 * t + 0.75 * t * t, 2e3 - 4 * t - t * t]
    n = len(f)
    tr = Tracks(f, np.zeros(n), np.array(["car"] * n, object), xy, np.full(n, np.nan), np.tile([4.0, 1.8], (n, 1)), FPS)
    nn = np.full(n, 7)
    np.testing.assert_allclose(derivative(tr, tr.xy, nn, 1), np.c_[3 + 1.5 * t, -4 - 2 * t], atol=1e-6)
    np.testing.assert_allclose(derivative(tr, tr.xy, nn, 2), np.tile([1.5, -2.0], (n, 1)), atol=1e-4)


@settings(max_examples=60, deadline=None)
@given(st.lists(road_user(), min_size=2, max_size=6))
def test_footprints_of_rows_equal_the_plain_tests(users):
    """Footprints.overlap / interval and ttc_rows: the same values, bit for bit, as
    overlaps, overlap_interval and ttc on the same rows."""
    xy = np.concatenate([u[0] for u in users])
    hd = np.concatenate([u[1] for u in users])
    size = np.concatenate([u[2] for u in users])
    vel = np.concatenate([u[3] for u in users])
    a, b = (x.ravel() for x in np.meshgrid(np.arange(len(users)), np.arange(len(users))))
    fp = Footprints(xy, hd, size)
    np.testing.assert_array_equal(fp.overlap(a, b), overlaps(xy[a], hd[a], size[a], xy[b], hd[b], size[b]))
    vx, vy = vel[:, 0].copy(), vel[:, 1].copy()
    e1, l1 = fp.interval(a, b, vx[b] - vx[a], vy[b] - vy[a])
    e2, l2 = overlap_interval(xy[a], hd[a], size[a], xy[b], hd[b], size[b], vel[b] - vel[a])
    np.testing.assert_array_equal(e1, e2)
    np.testing.assert_array_equal(l1, l2)
    np.testing.assert_array_equal(ttc_rows(fp, vx, vy, a, b, 30.0),
                                  ttc(xy[a], hd[a], size[a], vel[a], xy[b], hd[b], size[b], vel[b], 30.0))


def as_set(p):
    return set(map(tuple, np.asarray(p).tolist()))


@pytest.mark.parametrize("seed", [0, 1])
def test_pair_searches_with_rows_apart(seed, monkeypatch):
    """Same-frame pairs listed frame by frame = the k-d tree's (forced either way); rows
    ``apart`` (pedestrians): the same pairs less those of two pedestrians, in space-time
    boxes too."""
    tr = traffic(seed, n=20)
    rows = np.arange(len(tr))
    ped = class_rows(tr.cls, "pedestrian")
    assert 0 < ped.sum() < len(tr)

    def both(p):
        return ped[p[:, 0]] & ped[p[:, 1]]

    kd = near_pairs(tr, rows, 8.0, 0.0)
    assert len(kd) > 100 and both(kd).any()
    assert as_set(frame_pairs(tr, rows, 8.0)) == as_set(kd)
    assert as_set(frame_pairs(tr, rows, 8.0, ped)) == as_set(kd[~both(kd)])
    monkeypatch.setattr(encounters, "ENUMERATE_PER_ROW", 0)  # the k-d tree
    assert as_set(frame_pairs(tr, rows, 8.0, ped)) == as_set(kd[~both(kd)])
    for other in (None, rows[tr.track_id % 3 == 0]):
        r1 = rows if other is None else rows[tr.track_id % 3 != 0]
        box = near_pairs(tr, r1, 3.0, 2.0, other=other)
        got = near_pairs(tr, r1, 3.0, 2.0, other=other, apart=ped)
        assert len(got) == len(as_set(got))  # each pair once
        assert as_set(got) == as_set(box[~both(box)])
        assert (tr.track_id[got[:, 0]] < tr.track_id[got[:, 1]]).all()


def test_class_rows_any_case():
    cls = np.array(["car", "Pedestrian", "pedestrian", "pedestrian", "bicyclist", "PEDESTRIAN"], object)
    np.testing.assert_array_equal(class_rows(cls, "pedestrian"), [0, 1, 1, 1, 0, 1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pedestrian_pairs_left_out_early_change_no_row(seed):
    """Not searching pairs of two pedestrians (the table's default) leaves every other row
    as it is: the table with them searched and then dropped is the same."""
    tr = traffic(seed, n=20)
    fast = analyse(tr, ConflictOptions(all_pairs=True, workers=1))
    full = analyse(tr, ConflictOptions(all_pairs=True, pedestrian_pairs=True, workers=1))
    c = full.columns
    keep = ~((c["class_a"] == "pedestrian") & (c["class_b"] == "pedestrian"))
    assert (~keep).any()
    for k, v in fast.columns.items():
        np.testing.assert_array_equal(v, c[k][keep], err_msg=k)


def test_pair_frames_sorted_by_pair_then_frame():
    tr = traffic(4, n=20)
    mot = motion(tr)
    pf = pair_frames(tr, mot, ConflictOptions(), data=RowData(tr, mot))
    tid = tr.track_id
    keys = np.c_[tid[pf.a], tid[pf.b], tr.frame[pf.a]]
    assert len(keys) > 100
    np.testing.assert_array_equal(np.lexsort(keys.T[::-1]), np.arange(len(keys)))
    assert (tid[pf.a] < tid[pf.b]).all()


def straight_traffic(seed: int, n: int = 16) -> Tracks:
    """Road users at constant velocity, straight (no noise): the search's footprints grown by
    the travel to the next frame then hold every frame in between exactly."""
    rng = np.random.default_rng(seed)
    fr, tid, cls, xy, hd, size = [], [], [], [], [], []
    kinds = [("car", (4.4, 1.8), 10.0), ("pedestrian", (0.6, 0.6), 1.4), ("bicyclist", (1.8, 0.6), 5.0)]
    for i in range(n):
        c, s, v = kinds[rng.integers(0, 3)]
        f0, m = int(rng.integers(0, 60)), int(rng.integers(90, 240))
        ang = rng.choice([0, np.pi / 2, np.pi, -np.pi / 2]) + rng.normal(0, 0.2)
        u = np.array([np.cos(ang), np.sin(ang)])
        t = np.arange(m) / FPS
        p = rng.uniform(-6, 6, 2) - u * v * m / FPS / 2 + v * t[:, None] * u
        fr.append(f0 + np.arange(m))
        tid.append(np.full(m, i + 1))
        cls += [c] * m
        xy.append(p)
        hd.append(np.full(m, ang))
        size.append(np.tile(s, (m, 1)))
    return Tracks(np.concatenate(fr), np.concatenate(tid), np.array(cls, object), np.concatenate(xy),
                  np.concatenate(hd), np.concatenate(size), FPS)


@pytest.mark.parametrize("seed", range(4))
def test_pet_frames_are_the_closest_in_time_earliest(seed):
    """Per pair of road users, the pair of frames PET's search returns is, among all pairs of
    frames whose footprints overlap at most window_s apart (brute force), the closest in
    time, and of those the earliest."""
    tr = straight_traffic(seed)
    mot = motion(tr)
    opts = PetOptions()
    got = overlapping_rows(tr, mot, opts)
    assert len(got) >= 3
    tid, frame = tr.track_id, tr.frame
    # the frames the search covers: those whose nearest sample (every 3rd frame) is a moving
    # row (a track's first row has no velocity yet)
    s = int(round(opts.sample_s * FPS))
    moving = {(t, f) for t, f, v in zip(tid, frame, mot.speed) if v >= opts.moving_mps}
    covered = np.array([(t, s * round(f / s)) in moving for t, f in zip(tid, frame)])
    max_gap = int(np.floor(opts.window_s * FPS + 1e-9))
    found = {}
    for ta in np.unique(tid):
        for tb in np.unique(tid):
            if tb <= ta:
                continue
            ra, rb = np.flatnonzero((tid == ta) & covered), np.flatnonzero((tid == tb) & covered)
            A, B = (x.ravel() for x in np.meshgrid(ra, rb, indexing="ij"))
            g = np.abs(frame[A] - frame[B])
            ok = g <= max_gap
            A, B, g = A[ok], B[ok], g[ok]
            hit = overlaps(tr.xy[A], mot.heading[A], tr.size[A], tr.xy[B], mot.heading[B], tr.size[B])
            if hit.any():
                A, B, g = A[hit], B[hit], g[hit]
                i = np.lexsort((frame[A] > frame[B], np.minimum(frame[A], frame[B]), g))[0]
                found[(ta, tb)] = (frame[A[i]], frame[B[i]])
    mine = {(tid[a], tid[b]): (frame[a], frame[b]) for a, b in got}
    assert mine == found


@pytest.mark.parametrize("case", ["follower", "crossing", "turning"])
def test_pet_interval_without_noise_is_the_tables_pet(case):
    """The draws' PET is searched over the whole encounter as the table's is: with no pose
    error (r90 = 0) every draw is the tracks themselves, so the interval is the table's PET."""
    from seg2pose.safety.intervals import IntervalOptions, conflict_intervals
    from tests.seg2pose.safety.test_safety import crossing, follower, turning_car_and_pedestrian

    tr = {"follower": follower, "crossing": crossing,
          "turning": lambda: turning_car_and_pedestrian()[0]}[case]()
    table = analyse(tr, ConflictOptions())
    pet = table.columns["pet_s"][0]
    assert np.isfinite(pet)
    iv = conflict_intervals(tr, table, ConflictOptions(), IntervalOptions(draws=5),
                            r90=np.zeros(len(tr)))
    assert iv["pet_found_share"][0] == 1.0
    assert iv["pet_lo_s"][0] == pytest.approx(pet, abs=1e-9)
    assert iv["pet_hi_s"][0] == pytest.approx(pet, abs=1e-9)


@pytest.mark.parametrize("origin", [0.0, 1e3, 1e5, -3.7e4])
def test_braking_to_a_standstill_stays_braking(origin):
    """A car braking at 4 m/s^2 to an exact stop, then standing (noise-free, as ground truth
    is): up to the stop the acceleration along its travel is -4 m/s^2 (no lag: the centred
    fit), also in the last frames where the speed is below moving and the heading gives the
    direction; from 2 frames after the stop it stands (acceleration 0): wherever the world's
    origin is (the sign of a zero velocity is not the rounding's)."""
    t = np.arange(0, 6, 1 / FPS)
    s = np.where(t < 2.5, 10 * t - 2 * t * t, 12.5)
    n = len(t)
    tr = Tracks(np.arange(n), np.ones(n, int), np.array(["car"] * n, object),
                np.c_[origin + s, np.full(n, origin)], np.zeros(n), np.tile([4.0, 1.8], (n, 1)), FPS)
    m = motion(tr)
    f = np.arange(n)
    np.testing.assert_allclose(m.along[(f >= 2) & (f <= 73)], -4.0, atol=1e-4)
    np.testing.assert_allclose(m.along[f >= 78], 0.0, atol=1e-4)
    braking = m.acc[:, 0] < -0.5
    np.testing.assert_allclose(m.along[braking], m.acc[braking, 0])


@pytest.mark.parametrize("case", ["follower", "crossing", "turning"])
def test_pet_does_not_depend_on_where_the_frame_count_starts(case):
    """The same two tracks with their frames numbered from another start (77777: the
    turning car's exit point then fell on the wrong side of the pedestrian's edge by rounding,
    PET 0.792 s instead of 0.760 s) give the same PET to 1e-9 s; the turning case's is the
    hand value 2 - (0.9 + 0.3) / 1.4 - (2 + 0.3) / 6 (test_safety's)."""
    from tests.seg2pose.safety.test_safety import crossing, follower, turning_car_and_pedestrian

    make = {"follower": follower, "crossing": crossing,
            "turning": lambda: turning_car_and_pedestrian()[0]}[case]
    got = []
    for offset in (0, 1, 2, 77777, 10**6 + 1):
        tr = make()
        tr.frame = tr.frame + offset
        got.append(float(pet(tr, motion(tr), PetOptions()).pet[0]))
    assert max(got) - min(got) <= 1e-9
    hand = {"follower": 0.4, "crossing": 1.42, "turning": 2.0 - 1.2 / 1.4 - 2.3 / 6.0}[case]
    assert got[0] == pytest.approx(hand, abs=1e-6)


def test_smoothed_positions_reproduce_a_quadratic_and_match_the_per_row_fit():
    """Order 0 of ``derivative`` is the local quadratic's value: a constant acceleration's
    positions come back exactly (centred windows and the track's ends alike), and on noisy
    positions the correlation with fixed weights equals the per-row least-squares fit."""
    t = np.arange(0, 3, 1 / FPS)
    x = 3 + 2 * t - 1.5 * t * t
    tr = Tracks(np.arange(len(t)), np.ones(len(t), np.int64), np.array(["car"] * len(t), object),
                np.c_[x, 0.5 * x], np.zeros(len(t)), np.tile([4.0, 1.8], (len(t), 1)), FPS)
    for n in (5, 11, 31):
        np.testing.assert_allclose(derivative(tr, tr.xy, np.full(len(tr), n), 0), tr.xy, atol=1e-9)
    noisy = tr.with_xy(tr.xy + np.random.default_rng(0).normal(0, 0.1, tr.xy.shape))
    n = np.full(len(tr), 21)
    st, en = segments(noisy)
    rows = np.arange(len(tr))
    np.testing.assert_allclose(derivative(noisy, noisy.xy, n, 0),
                               _fit_rows(noisy, noisy.xy, n, 0, rows, st, en), atol=1e-9)


def test_fast_errors_measure_scale_and_correlation():
    """``intervals.fast_errors``: white residuals of 0.2 m give sigma 0.2 and a lag-1
    correlation near 0; AR(1) residuals with rho 0.8 give rho near 0.8 (20,000 frames)."""
    from seg2pose.safety.intervals import ar1_noise, fast_errors

    rng = np.random.default_rng(1)
    n = 20000
    tr = Tracks(np.arange(n), np.ones(n, np.int64), np.array(["car"] * n, object), np.zeros((n, 2)),
                np.zeros(n), np.tile([4.0, 1.8], (n, 1)), FPS)
    sig, rho = fast_errors(tr, rng.normal(0, 0.2, (n, 2)))
    assert sig[0] == pytest.approx(0.2, rel=0.03) and abs(rho[0]) < 0.03
    sig, rho = fast_errors(tr, 0.2 * ar1_noise(n, 1, 0.8, rng)[0])
    assert sig[0] == pytest.approx(0.2, rel=0.1) and rho[0] == pytest.approx(0.8, abs=0.03)
