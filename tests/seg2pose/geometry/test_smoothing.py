"""Smoothing along tracks: hand-computed windows, exact lines, gaps, untracked and NaN rows,
and a brute-force comparison on random tracks."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.geometry.smoothing import smooth_along_tracks


def brute(track, frame, values, h, degree):
    out = values.astype(float).copy()
    ok = (track >= 0) & np.isfinite(values).all(axis=1)
    for i in np.flatnonzero(ok):
        w = ok & (track == track[i]) & (np.abs(frame - frame[i]) <= h)
        t, v = frame[w].astype(float), values[w]
        if degree == 1 and len(np.unique(t)) > 1:
            A = np.column_stack([np.ones_like(t), t - frame[i]])
            out[i] = np.linalg.lstsq(A, v, rcond=None)[0][0]
        else:
            out[i] = v.mean(axis=0)
    return out


def test_mean_by_hand_with_a_gap_and_two_tracks():
    track = np.array([1, 1, 1, 1, 2, 2])
    frame = np.array([0, 1, 2, 5, 0, 1])
    v = np.array([[0.0], [3.0], [6.0], [9.0], [100.0], [200.0]])
    out = smooth_along_tracks(track, frame, v, 1)
    # frame 0: {0, 1}; frame 1: {0, 1, 2}; frame 2: {1, 2}; frame 5 alone (gap); track 2 apart
    np.testing.assert_allclose(out[:, 0], [1.5, 3.0, 4.5, 9.0, 150.0, 150.0])


def test_a_line_is_kept_exactly_by_degree_one_even_at_the_track_ends():
    frame = np.arange(20)
    v = np.column_stack([3.0 + 0.25 * frame, -2.0 * frame])
    out = smooth_along_tracks(np.zeros(20, int), frame, v, 4, degree=1)
    np.testing.assert_allclose(out, v, atol=1e-9)
    # the mean lags at the ends of a moving track: that is why positions use degree 1
    assert abs(smooth_along_tracks(np.zeros(20, int), frame, v, 4)[0, 0] - v[0, 0]) > 0.4


def test_untracked_and_nan_rows_are_left_alone_and_ignored():
    track = np.array([-1, 0, 0, 0])
    frame = np.array([1, 0, 1, 2])
    v = np.array([[50.0], [1.0], [np.nan], [3.0]])
    out = smooth_along_tracks(track, frame, v, 1)
    assert out[0, 0] == 50.0 and np.isnan(out[2, 0])
    np.testing.assert_allclose(out[[1, 3], 0], [1.0, 3.0])  # frame 0 and 2 are 2 apart


def test_zero_window_returns_a_copy():
    v = np.array([[1.0, 2.0]])
    out = smooth_along_tracks(np.array([0]), np.array([0]), v, 0)
    assert out is not v and np.array_equal(out, v)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(-1, 3), st.integers(0, 40)), min_size=1, max_size=60,
                unique=True),
       st.integers(1, 6), st.sampled_from([0, 1]), st.integers(0, 10**6))
def test_equals_brute_force(rows, h, degree, seed):
    track = np.array([r[0] for r in rows])
    frame = np.array([r[1] for r in rows])
    v = np.random.default_rng(seed).normal(size=(len(rows), 2)) * 5 + 20
    np.testing.assert_allclose(smooth_along_tracks(track, frame, v, h, degree),
                               brute(track, frame, v, h, degree), atol=1e-7)


# ----------------------------------------------------------------------------------------------
# the pipeline's --smooth and the paper table fused again from its views


def test_paper_table_smooth_equals_refused_views(tmp_path):
    """paper-table --smooth N: every run (the baseline's too) is the raw run's poses smoothed
    along each track; fusing a finished table's views.csv again gives the same figures."""
    import json

    from scene_fixtures import make_tiny_scene

    from seg2pose.eval.paper_table import paper_table, refuse_table
    from seg2pose.io.poses import read_poses

    tiny = make_tiny_scene(tmp_path / "tiny")
    raw, _ = paper_table(tiny, out_dir=tmp_path / "raw", baseline_only=True, progress=False,
                         configs=["mono-1", "tri-I"])
    sm, _ = paper_table(tiny, out_dir=tmp_path / "sm", baseline_only=True, progress=False,
                        configs=["mono-1", "tri-I"], smooth=3)
    a = read_poses(raw / "runs" / "tri-I-baseline" / "poses.csv")
    b = read_poses(sm / "runs" / "tri-I-baseline" / "poses.csv")
    np.testing.assert_array_equal(a.track_id, b.track_id)
    np.testing.assert_allclose(b.xyz[:, :2], smooth_along_tracks(a.track_id, a.frame, a.xyz[:, :2],
                                                                 3, degree=1), atol=1e-9)
    assert not np.allclose(a.xyz[:, :2], b.xyz[:, :2])
    assert json.loads((sm / "runs" / "tri-I-baseline" / "run.json").read_text())["smooth_frames"] == 3
    for out, n in ((raw, 0), (sm, 3)):
        want = json.loads((out / "results.json").read_text())["results"]
        got = refuse_table(tiny, raw, n)
        assert set(got) == set(want)
        for k, r in got.items():
            assert r.mean_error == pytest.approx(want[k]["mean_error"], abs=1e-9)


def test_bench_summary_has_the_smoothed_columns(tmp_path):
    from seg2pose.eval.accuracy import SeedResult, read_table, summary

    r = SeedResult(5)
    for name, (b, s), suffix in (("raw", (0.30, 0.15), ""), ("sm", (0.25, 0.10), "+smooth")):
        p = tmp_path / name
        p.mkdir()
        p.joinpath("results.json").write_text(json.dumps({"results": {
            "mono-1 baseline": {"mean_error": b}, "mono-1 S2PN": {"mean_error": s}}}))
        read_table(p / "results.json", "s2pn", r, suffix)
    text = summary([r], ("s2pn",))
    # raw 0.15 / 0.30; smoothed over the plain baseline 0.10 / 0.30; over the smoothed 0.10 / 0.25
    assert "0.500x" in text and "0.333x" in text and "0.400x" in text
    assert "s2pn+smooth / baseline+smooth" in text
