"""PET's refinement between frames (``pet.refine``, ``pet.latest_exit``): the first road
user's exit and the second one's entry found together, so that millimetres of noise at the
edge the exit point touches cost no frame (the crossing read 1.442 s for 1.420 s), and steady
following keeps its exact headway (a fix that moved the entry alone read 0.387 s for 0.41 s)."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.safety.conflicts import ConflictOptions, analyse
from seg2pose.safety.footprints import overlaps
from seg2pose.safety.pet import latest_exit
from tests.seg2pose.safety.test_safety import CAR, FPS, make_tracks, one

MM = 1e-3


def noisy_crossing(seed: int):
    """test_safety's right-angle crossing (car 1 along +x through the origin at 3 s, car 2
    along +y at 5 s, 10 m/s, 4 x 1.8 m) with every position off by up to 1 mm (uniform, per
    coordinate and frame)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 8, 1 / FPS)
    f = np.arange(len(t))
    z = np.zeros(len(t))
    e1, e2 = rng.uniform(-MM, MM, (2, len(t), 2))
    return make_tracks([(1, "car", f, np.c_[10 * (t - 3), z] + e1, 0.0, CAR),
                        (2, "car", f, np.c_[z, 10 * (t - 5)] + e2, np.pi / 2, CAR)])


@pytest.mark.parametrize("seed", [0, 4, 5, 7])
def test_crossing_with_mm_noise_at_the_edge(seed):
    """Car 1's rear leaves the 1.8 x 1.8 m shared square when its centre is at x = 0.9 + 2 m
    (t = 3.29 s); car 2's front enters it when its centre is at y = -0.9 - 2 m (t = 4.71 s):
    PET 1.420 s. The exit point lies on car 2's footprint's edge; 1 mm of noise moves each
    footprint by at most sqrt(2) mm, which at 10 m/s shifts the exit and the entry by at most
    2 * 1.42 mm / 10 m/s = 0.28 ms each: PET within 1 ms of 1.420 s (seeds 4, 5 and 7 read
    1.443 s: car 2's sideways noise took it off the exit point's edge at once, and its
    entry was put at its frame, 142 = 4.733 s)."""
    table = analyse(noisy_crossing(seed), ConflictOptions(workers=1))
    r = one(table)
    assert r["pet_first_track"] == 1
    assert r["pet_s"] == pytest.approx(1.42, abs=1e-3)
    assert table.pets.t_exit[0] == pytest.approx(3.29, abs=1e-3)
    assert table.pets.t_enter[0] == pytest.approx(4.71, abs=1e-3)


def steady_following(gap_m: float, noise_m: float, seed: int = 0):
    """Leader (track 1) and follower (track 2) at 10 m/s along +x, ``gap_m`` bumper to bumper
    (cars 4 m long), positions off by up to ``noise_m`` (uniform)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 5, 1 / FPS)
    f = np.arange(len(t))
    z = np.zeros(len(t))
    e1, e2 = rng.uniform(-noise_m, noise_m, (2, len(t), 2)) if noise_m else (0.0, 0.0)
    lead = 30.0 + 10 * t
    return make_tracks([(1, "car", f, np.c_[lead, z] + e1, 0.0, CAR),
                        (2, "car", f, np.c_[lead - 4.0 - gap_m, z] + e2, 0.0, CAR)])


@pytest.mark.parametrize("gap_m, noise_m", [(4.1, 0.0), (4.1, MM), (5.0, 0.0), (2.95, MM)])
def test_steady_following_keeps_its_headway(gap_m, noise_m):
    """The leader's rear is at 30 - 2 + 10 s at time s, the follower's front at
    30 - 4 - gap + 2 + 10 u at time u: the same spot when u - s = gap / 10 m/s (4.1 m: PET
    0.41 s, between frames 12 and 13 of the headway). With 1 mm of noise per coordinate the
    bumpers move by at most 2 mm: 0.2 ms at 10 m/s, the velocities between frames included
    within 1 ms."""
    r = one(analyse(steady_following(gap_m, noise_m), ConflictOptions(workers=1)))
    assert r["conflict"] == 0 and r["pet_only"] == 1 and r["pet_first_track"] == 1
    assert r["pet_s"] == pytest.approx(gap_m / 10.0, abs=1e-9 if noise_m == 0 else 1e-3)


def test_latest_exit_is_the_best_of_a_fine_grid():
    """Random pairs of overlapping footprints (any headings, sizes, velocities, a frame of
    1/30 s each way): the offsets (a, b) found keep the footprints overlapping (to 1e-7 m)
    and a + b is at least the best of a 201 x 201 grid over [0, 1/30]^2 and within two grid
    steps of it (the largest a + b is a corner of a convex polygon, between grid points)."""
    rng = np.random.default_rng(3)
    K = 120
    r, va, vb = rng.normal(0, 2, (K, 2)), rng.normal(0, 10, (K, 2)), rng.normal(0, 10, (K, 2))
    ha, hb = rng.uniform(0, 2 * np.pi, (2, K))
    sa = np.c_[rng.uniform(0.5, 5, K), rng.uniform(0.5, 2, K)]
    sb = np.c_[rng.uniform(0.5, 5, K), rng.uniform(0.5, 2, K)]
    dt = np.full(K, 1 / 30)
    keep = overlaps(np.zeros((K, 2)), ha, sa, r, hb, sb)
    assert keep.sum() > 30
    a, b = latest_exit(r, va, vb, ha, sa, hb, sb, dt, dt)
    assert ((a >= 0) & (a <= dt) & (b >= 0) & (b <= dt)).all()
    g = np.linspace(0, 1 / 30, 201)
    A, B = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    n = len(A)
    for k in np.flatnonzero(keep):
        at = r[k] + va[k] * a[k] + vb[k] * b[k]
        assert overlaps(np.zeros((1, 2)), ha[k:k + 1], sa[k:k + 1] + 1e-7, at[None], hb[k:k + 1],
                        sb[k:k + 1] + 1e-7)[0], k
        hit = overlaps(np.zeros((n, 2)), np.full(n, ha[k]), np.tile(sa[k], (n, 1)),
                       r[k] + va[k] * A[:, None] + vb[k] * B[:, None], np.full(n, hb[k]),
                       np.tile(sb[k], (n, 1)))
        grid = (A + B)[hit].max()
        assert grid - 1e-12 <= a[k] + b[k] <= grid + 2 * (g[1] - g[0]), k
