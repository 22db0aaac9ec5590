"""The measures as the literature defines them, on hand-made trajectories whose answers are
derived by hand here: Hayward's TTC at the current velocity (constant-acceleration braking,
a stop behind a standing car, a far head-on), the Swedish TCT's Time-to-Accident at the onset
of braking or swerving, PET across missing frames, SSAM's conflict rule (steady following is
no conflict) and its types by angle. Cars 4 x 1.8 m, pedestrians 0.6 x 0.6 m, 30 fps."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.safety.conflicts import ConflictOptions, analyse
from seg2pose.safety.gaps import fill_gaps, jumps
from seg2pose.safety.intervals import IntervalOptions, conflict_intervals
from seg2pose.safety.kinematics import motion
from seg2pose.safety.measures import angle_type, footprint_gap, max_delta_v
from tests.seg2pose.safety.test_safety import CAR, FPS, make_tracks, one

PED = (0.6, 0.6)
OPTS = ConflictOptions(workers=1)


def braking_follower():
    """Leader at 10 m/s; follower at 15 m/s, its front 4 m behind the leader's rear when it
    starts braking at 5 m/s^2 (t = 1 s, frame 30) for 1 s (then 10 m/s)."""
    t = np.arange(0, 4, 1 / FPS)
    u = np.clip(t - 1, 0, 1)
    f = np.arange(len(t))
    lead = 10 * t
    foll = np.where(t < 1, 15 * t, 15 + 15 * u - 2.5 * u ** 2 + 10 * np.maximum(t - 2, 0))
    foll = foll - foll[30] + lead[30] - 4.0 - 4.0  # 4 m bumper gap at frame 30
    z = np.zeros(len(t))
    return make_tracks([(1, "car", f, np.c_[lead, z], np.nan, CAR), (2, "car", f, np.c_[foll, z], np.nan, CAR)])


def test_braking_follower_min_ttc_and_ta():
    """u s after braking starts: gap g = 4 - 5u + 2.5u^2, closing speed 5 - 5u, so TTC =
    g / (5 - 5u); d/du = 0 at 2.5u^2 - 5u + 1 = 0, u = 1 - sqrt(0.6) = 0.2254 s: TTC 0.775 s
    (a trailing 1 s window read 0.444 s). TA: the TTC at the onset (u = 0) with the speed
    before it, 4 m / 5 m/s = 0.800 s at 15 m/s, the follower evading by braking; MaxD -5."""
    r = one(analyse(braking_follower(), OPTS))
    u = 1 - np.sqrt(0.6)
    exact = (4 - 5 * u + 2.5 * u * u) / (5 - 5 * u)
    assert exact == pytest.approx(0.7746, abs=1e-4)
    assert r["min_ttc_s"] == pytest.approx(exact, abs=0.01)
    assert r["conflict"] == 1 and r["type"] == "rear-end" and r["ssam_type"] == "rear-end"
    assert r["ta_s"] == pytest.approx(0.8, abs=0.01) and r["ta_frame"] == 30
    assert r["conflicting_speed_mps"] == pytest.approx(15.0, abs=0.05)
    assert (r["evasive_track"], r["evasive_kind"], r["second_track"]) == (2, "brake", 2)
    assert r["max_d_mps2"] == pytest.approx(-5.0, abs=0.05)  # a 1 s pulse reads in full
    assert r["max_decel_b_mps2"] == pytest.approx(5.0, abs=0.05)
    assert r["min_distance_m"] == pytest.approx(1.5, abs=1e-6)  # 4 - (5 - 2.5) m, bumper to bumper


def test_cut_in_then_braking():
    """Car 2 (10 m/s) moves from the next lane (3.5 m) into car 1's lane between t = 0.5 and
    4 s (a half cosine: at most 1.6 m/s and 1.4 m/s^2 sideways, no evasive action); at 4.5 s
    its rear 4 m ahead of car 1's front (15 m/s), which brakes at
    5 m/s^2 for 1 s from 4.5 s: from there it is the braking follower, min TTC 0.775 s (during
    the cut-in the TTC, bound by the 5 m/s closing along the lane, is above 0.8 s), a
    rear-end conflict once car 2 is in the lane; TA 0.8 s at 15 m/s by car 1."""
    t = np.arange(0, 7, 1 / FPS)
    f = np.arange(len(t))
    u = np.clip(t - 4.5, 0, 1)
    x1 = np.where(t < 4.5, 15 * t, 67.5 + 15 * u - 2.5 * u ** 2 + 10 * np.maximum(t - 5.5, 0))
    x2 = 67.5 + 4.0 + 4.0 + 10 * (t - 4.5)
    y2 = 3.5 * (1 + np.cos(np.pi * np.clip(t - 0.5, 0, 3.5) / 3.5)) / 2
    tr = make_tracks([(1, "car", f, np.c_[x1, np.zeros(len(t))], np.nan, CAR),
                      (2, "car", f, np.c_[x2, y2], np.nan, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["min_ttc_s"] == pytest.approx(0.7746, abs=0.01)
    assert r["min_ttc_frame"] == pytest.approx(30 * (4.5 + 1 - np.sqrt(0.6)), abs=1)
    assert r["ssam_type"] == "rear-end" and r["conflict"] == 1
    assert r["ta_s"] == pytest.approx(0.8, abs=0.01) and r["evasive_track"] == 1
    assert r["conflicting_speed_mps"] == pytest.approx(15.0, abs=0.05)


def test_stop_behind_standing_car():
    """10 m/s braking at 2.5 m/s^2, stopping 2 m short of a standing car: tau s before the
    stop, gap 2 + 1.25 tau^2 and speed 2.5 tau, TTC = 0.8 / tau + 0.5 tau, least at tau =
    sqrt(1.6): TTC = sqrt(2 * 2 / 2.5) = 1.265 s (a trailing window read 0.860 s)."""
    t = np.arange(0, 7, 1 / FPS)
    f = np.arange(len(t))
    tau = np.maximum(4.0 - t, 0)  # stops at t = 4 s
    x = -2.0 - 1.25 * tau ** 2 - 4.0  # its centre: front 2 m short of the standing car's rear
    z = np.zeros(len(t))
    tr = make_tracks([(1, "car", f, np.c_[np.zeros(len(t)), z], 0.0, CAR), (2, "car", f, np.c_[x, z], 0.0, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["min_ttc_s"] == pytest.approx(np.sqrt(2 * 2 / 2.5), abs=0.01)
    assert r["conflict"] == 1


def pedestrian_ahead():
    """A car at 12 m/s along +x brakes at 6 m/s^2 from t = 2 s (frame 60); a pedestrian walks
    across its lane along +y at 1.4 m/s, 1.29 * 1.4 m short of the lane's centre then, and
    the car's front 15.48 m before the pedestrian's near edge."""
    t = np.arange(0, 5, 1 / FPS)
    f = np.arange(len(t))
    u = np.clip(t - 2, 0, 2)  # stops after 2 s, 12 m later
    front = np.where(t < 2, 12 * (t - 2), 12 * u - 3 * u ** 2)  # 0 at the onset
    car = np.c_[front - 2.0, np.zeros(len(t))]
    x_ped = 15.48 + 0.3
    yp = -1.29 * 1.4 + 1.4 * (t - 2)
    return make_tracks([(1, "car", f, car, np.nan, CAR),
                        (2, "pedestrian", f, np.c_[np.full(len(t), x_ped), yp], np.nan, PED)])


def test_time_to_accident_braking_for_a_pedestrian():
    """At the onset the pedestrian is 1.806 m from the lane's centre line: it enters the car's
    band (|y| <= 0.9 + 0.3 m) after 0.433 s and stays 1.714 s; the car's front reaches its
    edge 15.48 / 12 = 1.29 s later, within that: TA 1.29 s at 12.0 m/s, by the car (a
    trailing window read 0.72 s at 8.8 m/s, 1 s late). Serious by the boundary 12 / 8 = 1.5 s."""
    r = one(analyse(pedestrian_ahead(), OPTS))
    assert r["ta_s"] == pytest.approx(1.29, abs=0.02)
    assert r["conflicting_speed_mps"] == pytest.approx(12.0, abs=0.05)
    assert (r["evasive_track"], r["evasive_kind"], r["tct_severity"]) == (1, "brake", "serious")
    assert r["type"] == "pedestrian" and r["ssam_type"] == "crossing"


def test_tct_boundary_stand_in_and_curve():
    """The severity boundary: the stand-in stops from v at 4 m/s^2 (12 m/s: 12 / 8 = 1.5 s;
    at 3 m/s^2: 2.0 s); a study's curve (km/h, s) is joined by straight lines (30 km/h
    between (10, 0.5) and (50, 1.5): 1.0 s), flat below its first point, and continued
    along its last segment (110 km/h: 3.0 + 10 * 1.5 / 50 = 3.3 s). The pedestrian case (TA
    1.29 s at 43.2 km/h) is serious by the stand-in and slight below a curve through
    (0, 0) and (100, 2) (0.864 s there)."""
    from seg2pose.safety.evasive import EvasiveOptions, tct_boundary_s

    assert tct_boundary_s([12.0])[0] == pytest.approx(1.5)
    assert tct_boundary_s([12.0], EvasiveOptions(tct_decel_mps2=3.0))[0] == pytest.approx(2.0)
    curve = EvasiveOptions(tct_curve=((10.0, 0.5), (50.0, 1.5), (100.0, 3.0)))
    got = tct_boundary_s(np.array([30.0, 5.0, 110.0]) / 3.6, curve)
    np.testing.assert_allclose(got, [1.0, 0.5, 3.3])
    low = ConflictOptions(workers=1, evasive=EvasiveOptions(tct_curve=((0.0, 0.0), (100.0, 2.0))))
    assert one(analyse(pedestrian_ahead(), low))["tct_severity"] == "slight"
    assert one(analyse(pedestrian_ahead(), OPTS))["tct_severity"] == "serious"


def test_time_to_accident_of_a_swerve():
    """A car at 10 m/s swerves left, its centre on an arc of radius 20 m (lateral acceleration
    5 m/s^2) from t = 2 s, its front 12 m behind a standing car's rear then: TA = 12 / 10 =
    1.2 s at 10 m/s."""
    v, R = 10.0, 20.0
    t = np.arange(0, 4, 1 / FPS)
    f = np.arange(len(t))
    phi = np.clip(v * (t - 2) / R, 0, None)
    x = np.where(t < 2, v * (t - 2), R * np.sin(phi))
    y = np.where(t < 2, 0.0, R * (1 - np.cos(phi)))
    h = np.where(t < 2, 0.0, phi)
    tr = make_tracks([(1, "car", f, np.c_[x, y], h, CAR),
                      (2, "car", f, np.tile([2.0 + 12.0 + 2.0, 0.0], (len(t), 1)), 0.0, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["ta_s"] == pytest.approx(1.2, abs=0.02)
    assert r["conflicting_speed_mps"] == pytest.approx(10.0, abs=0.05)
    assert (r["evasive_track"], r["evasive_kind"]) == (1, "swerve")


def test_pet_across_missing_frames():
    """Car 1 along +x through the origin at t = 3 s, car 2 along +y through it at 4.58 s, both
    10 m/s: car 1's rear leaves the 1.8 x 1.8 m shared square at 3 + 0.29 s, car 2's front
    enters it at 4.58 - 0.29 s: PET 1.000 s; car 2's frames 124-134 (0.37 s around its entry)
    are missing and interpolated."""
    t = np.arange(0, 8, 1 / FPS)
    f = np.arange(len(t))
    z = np.zeros(len(t))
    keep = (f < 124) | (f > 134)
    tr = make_tracks([(1, "car", f, np.c_[10 * (t - 3), z], 0.0, CAR),
                      (2, "car", f[keep], np.c_[z, 10 * (t - 4.58)][keep], np.pi / 2, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["pet_s"] == pytest.approx(1.0, abs=0.01)
    assert r["pet_first_track"] == 1 and r["pet_only"] == 1 and r["conflict"] == 0
    filled, added, stats = fill_gaps(tr, 1.0)
    assert stats == {"filled": 1, "frames": 11, "open": 0} and added.sum() == 11


def test_far_head_on_is_found():
    """Head-on in one lane at 15 m/s each; car 2 turns off (radius 10 m, to its right) when
    the bumpers are 34.5 m apart: TTC then 34.5 / 30 = 1.15 s, the centres 38.5 m apart (no
    fixed search distance may drop it)."""
    t = np.arange(0, 4, 1 / FPS)
    f = np.arange(len(t))
    t0 = 2.0
    a = np.c_[15 * t, np.zeros(len(t))]
    xb0 = 15 * t0 + 2.0 + 34.5 + 2.0  # car 2's centre at t0
    phi = np.clip(15 * (t - t0) / 10.0, 0, np.pi / 2)
    extra = np.maximum(15 * (t - t0) - 10.0 * np.pi / 2, 0)
    b = np.where((t < t0)[:, None], np.c_[xb0 + 15 * (t0 - t), np.zeros(len(t))],
                 np.c_[xb0 - 10 * np.sin(phi), 10 * (1 - np.cos(phi)) + extra])
    tr = make_tracks([(1, "car", f, a, np.nan, CAR), (2, "car", f, b, np.nan, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["min_ttc_s"] == pytest.approx(1.15, abs=0.05)
    fr = int(r["min_ttc_frame"])
    assert np.hypot(*(a[fr] - b[fr])) > 35
    assert r["conflict"] == 1 and r["ssam_type"] == "head-on"


def test_steady_following_is_not_a_conflict():
    """Two cars at 10 m/s, 0.5 s (5 m) apart bumper to bumper: no collision course, so no
    SSAM conflict; PET 0.5 s puts the pair on the PET-only list."""
    t = np.arange(0, 5, 1 / FPS)
    f = np.arange(len(t))
    z = np.zeros(len(t))
    tr = make_tracks([(1, "car", f, np.c_[10 * t + 9.0, z], 0.0, CAR), (2, "car", f, np.c_[10 * t, z], 0.0, CAR)])
    r = one(analyse(tr, OPTS))
    assert r["conflict"] == 0 and r["pet_only"] == 1 and np.isnan(r["min_ttc_s"])
    assert r["pet_s"] == pytest.approx(0.5, abs=1e-6)
    assert r["type"] == "rear-end" and r["angle_deg"] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("angle,kind", [(0, "rear-end"), (29.9, "rear-end"), (30, "lane-change"),
                                        (-45, "lane-change"), (84.9, "lane-change"), (85, "crossing"),
                                        (-120, "crossing"), (150, "head-on"), (180, "head-on")])
def test_ssam_types_by_angle(angle, kind):
    """SSAM (FHWA-HRT-08-050): rear-end below 30 degrees, lane change below 85, crossing above;
    head-on from 150 (SSAM's crossing)."""
    assert angle_type([angle])[0] == kind


def test_merge_at_45_degrees_is_a_lane_change_with_a_signed_angle():
    """Car 2 along +x; car 1 joins from its right at 45 degrees (heading +45), both 10 m/s,
    meeting at the origin at t = 3 s: the angle from the first to the second is -45 degrees
    (the second, car 2, turned clockwise from car 1's direction), a lane change."""
    t = np.arange(0, 5, 1 / FPS)
    f = np.arange(len(t))
    d = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    tr = make_tracks([(1, "car", f, (10 * (t - 3.0))[:, None] * d, np.pi / 4, CAR),
                      (2, "car", f, np.c_[10 * (t - 3.0) - 1.0, np.zeros(len(t))], 0.0, CAR)])
    r = one(analyse(tr, ConflictOptions(workers=1, all_pairs=True)))
    assert r["ssam_type"] == "lane-change" and abs(r["angle_deg"]) == pytest.approx(45.0, abs=0.5)
    first_dir = 0.0 if r["second_track"] == 1 else 45.0
    second_dir = 45.0 if r["second_track"] == 1 else 0.0
    assert r["angle_deg"] == pytest.approx(second_dir - first_dir, abs=0.5)


def test_head_on_pass_in_adjacent_lanes_is_typed_head_on():
    """Cars at 10 m/s in opposite directions, lanes 3.5 m apart: no conflict, but typed by the
    angle at the closest approach: head-on, 180 degrees, DeltaS 20 m/s; the gap 3.5 - 1.8 m."""
    t = np.arange(0, 4, 1 / FPS)
    f = np.arange(len(t))
    tr = make_tracks([(1, "car", f, np.c_[10 * t - 20, np.zeros(len(t))], 0.0, CAR),
                      (2, "car", f, np.c_[20 - 10 * t, np.full(len(t), 3.5)], np.pi, CAR)])
    r = one(analyse(tr, ConflictOptions(workers=1, all_pairs=True)))
    assert r["conflict"] == 0 and r["ssam_type"] == "head-on"
    assert abs(r["angle_deg"]) == pytest.approx(180.0, abs=1e-6)
    assert r["delta_s_mps"] == pytest.approx(20.0, abs=1e-6)
    assert r["min_distance_m"] == pytest.approx(1.7, abs=1e-9)


def test_max_delta_v_and_gap():
    """Inelastic collision of a 1500 kg car and a 75 kg pedestrian at 10 m/s relative: the
    pedestrian's DeltaV is 1500 / 1575 * 10 = 9.52 m/s. Two unit squares 3 m apart along x,
    one turned 45 degrees: the gap is 3 - 0.5 - sqrt(0.5) m."""
    assert max_delta_v(["car"], ["pedestrian"], [10.0])[0] == pytest.approx(1500 / 1575 * 10)
    g = footprint_gap([[0.0, 0.0]], [0.0], [[1.0, 1.0]], [[3.0, 0.0]], [np.pi / 4], [[1.0, 1.0]])
    assert g[0] == pytest.approx(3 - 0.5 - np.sqrt(0.5))


def test_no_interval_without_r90():
    """Poses without an error radius get no interval (NaN, written empty), not one of zero
    width; with one, the TA interval holds the TA."""
    tr = pedestrian_ahead()
    table = analyse(tr, OPTS)
    ft = table.tracks
    assert ft is not None
    n = len(ft)
    none = conflict_intervals(ft, table, OPTS, IntervalOptions(draws=20), r90=np.full(n, np.nan))
    assert all(np.isnan(v[0]) for v in none.values())
    some = conflict_intervals(ft, table, OPTS, IntervalOptions(draws=40), r90=np.full(n, 0.2))
    assert some["ta_lo_s"][0] <= table.columns["ta_s"][0] <= some["ta_hi_s"][0]


def test_noisy_tracks_keep_ttc_within_its_interval():
    """The braking follower with 0.2 m of noise: each track's window widens with the noise
    measured from it (about 0.2 m), and the 90 % interval from r90 = 0.2 * 2.146 m holds the
    exact minimum TTC."""
    tr = braking_follower()
    rng = np.random.default_rng(3)
    noisy = tr.with_xy(tr.xy + rng.normal(0, 0.2, tr.xy.shape))
    mot = motion(noisy)
    assert mot.sigma.mean() == pytest.approx(0.2, rel=0.25)
    assert mot.n_vel.min() > 15
    table = analyse(noisy, OPTS)
    assert table.tracks is not None
    iv = conflict_intervals(table.tracks, table, OPTS, IntervalOptions(draws=100), r90=np.full(len(noisy), 0.2 * 2.146))
    assert iv["min_ttc_lo_s"][0] <= 0.7746 <= iv["min_ttc_hi_s"][0]


def test_jumps_are_found():
    """A car that moves 100 m between two frames is two road users under one id."""
    t = np.arange(0, 2, 1 / FPS)
    f = np.arange(len(t))
    x = np.where(f < 30, 10 * t, 10 * t + 100)
    tr = make_tracks([(1, "car", f, np.c_[x, np.zeros(len(t))], 0.0, CAR)])
    assert list(jumps(tr)) == [30]
