"""Streaming over time chunks (seg2pose.safety.conflicts): the table made chunk by chunk (in
one process or two) is the same, bit for bit, as the whole recording's, for encounters that
straddle chunk borders."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.safety.conflicts import ConflictOptions, analyse, format_conflicts
from seg2pose.safety.tracks import Tracks
from tests.seg2pose.safety.test_safety import FPS, crossing, follower

WHOLE = np.inf  # one chunk: the whole recording


def traffic(seed: int, n: int = 14, seconds: float = 12.0) -> Tracks:
    """Road users crossing a 40 m square in random directions at random speeds, some braking
    hard (evasive actions, so Time-to-Accident exists), some standing, with position noise:
    many pairs meet, touch and cross, at every time of the recording."""
    rng = np.random.default_rng(seed)
    fr, tid, cls, xy, hd, size = [], [], [], [], [], []
    kinds = [("car", (4.4, 1.8), 12.0), ("pedestrian", (0.6, 0.6), 1.5), ("bicyclist", (1.8, 0.6), 5.0)]
    for i in range(n):
        c, s, v = kinds[rng.integers(0, 3)]
        f0 = int(rng.integers(0, seconds * FPS / 2))
        m = int(rng.integers(2 * FPS, seconds * FPS - f0))
        t = np.arange(m) / FPS
        ang = rng.uniform(-np.pi, np.pi)
        speed = v * rng.uniform(0.0, 1.2) * np.ones(m)
        if rng.random() < 0.4:  # brakes at 5 m/s^2 from a random moment
            tb = rng.uniform(0, t[-1])
            speed = np.maximum(speed - 5.0 * np.clip(t - tb, 0, None), 0)
        dist = np.concatenate([[0], np.cumsum(speed[:-1] / FPS)])
        p0 = rng.uniform(-12, 12, 2) - dist[m // 2] * np.array([np.cos(ang), np.sin(ang)])
        p = p0 + dist[:, None] * np.array([np.cos(ang), np.sin(ang)]) + rng.normal(0, 0.03, (m, 2))
        fr.append(f0 + np.arange(m))
        tid.append(np.full(m, i + 1))
        cls += [c] * m
        xy.append(p)
        hd.append(np.full(m, ang if rng.random() < 0.7 else np.nan))  # some headings unknown
        size.append(np.tile(s, (m, 1)))
    return Tracks(np.concatenate(fr), np.concatenate(tid), np.array(cls, object), np.concatenate(xy),
                  np.concatenate(hd), np.concatenate(size), FPS)


def assert_same(tracks: Tracks, **kw) -> None:
    whole = analyse(tracks, ConflictOptions(chunk_s=WHOLE, workers=1, **kw))
    assert len(whole) > 0
    for chunk_s, workers in ((0.5, 1), (1.0, 2), (2.7, 1)):
        part = analyse(tracks, ConflictOptions(chunk_s=chunk_s, workers=workers, **kw))
        assert part.columns.keys() == whole.columns.keys()
        for k, v in whole.columns.items():
            np.testing.assert_array_equal(part.columns[k], v, err_msg=f"{k}, chunks of {chunk_s} s")
        assert format_conflicts(part, FPS) == format_conflicts(whole, FPS)
        assert part.compared == whole.compared  # every pair frame compared exactly once


def test_follower_encounter_across_chunks():
    """The follower's encounter lasts 7 s: chunks of 0.5-2.7 s cut it several times (the min
    TTC at frame 120 = 4 s sits right on a 0.5 s and 1 s border)."""
    assert_same(follower())


def test_crossing_across_chunks():
    assert_same(crossing())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_traffic_across_chunks(seed):
    tr = traffic(seed)
    whole = analyse(tr, ConflictOptions(chunk_s=WHOLE, workers=1, all_pairs=True, pedestrian_pairs=True))
    c = whole.columns
    # the case exercises what chunking could break: encounters straddling borders, Time-to-
    # Accident, PET, touching footprints (TTC 0)
    assert ((c["first_frame"] // FPS) != (c["last_frame"] // FPS)).sum() >= 3
    assert np.isfinite(c["ta_s"]).any() and np.isfinite(c["pet_s"]).any()
    assert (c["min_ttc_s"] == 0).any()
    assert_same(tr, all_pairs=True, pedestrian_pairs=True)
    assert_same(tr)


def test_pet_search_in_two_processes_is_the_same():
    """PET's own chunks (60 s) searched in two processes: the same overlapping rows."""
    from seg2pose.safety.kinematics import motion
    from seg2pose.safety.pet import PetOptions, overlapping_rows

    tr = traffic(3, n=20, seconds=30.0)
    mot = motion(tr)
    one_ = overlapping_rows(tr, mot, PetOptions(), chunk_s=4.0, workers=1)
    two = overlapping_rows(tr, mot, PetOptions(), chunk_s=4.0, workers=2)
    whole = overlapping_rows(tr, mot, PetOptions(), chunk_s=np.inf, workers=1)
    assert len(whole) > 3
    np.testing.assert_array_equal(one_, two)
    np.testing.assert_array_equal(one_, whole)
