"""Pipeline (normal positions -> residuals -> late fusion -> headings -> run folder) and the
evaluation of run folders, on a tiny hand-built 3-view scene."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scene_fixtures import SIZES, make_tiny_scene

from seg2pose.core.errors import InputError, S2PError
from seg2pose.geometry.normal import normal_positions
from seg2pose.io.mots import read_mots
from seg2pose.io.poses import PoseTable, read_poses, write_poses
from seg2pose.io.scene import Scene
from seg2pose.structures.masks import mask_centers


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Scene:
    return make_tiny_scene(tmp_path_factory.mktemp("tiny"))


def test_baseline_equals_mean_of_normal_positions(tiny, tmp_path):
    """Residual-free baseline on a 3-view configuration: each pose is the mean over the views
    of the views' normal positions (computed here independently, per camera)."""
    from seg2pose.io.run import read_views
    from seg2pose.method.pipeline import RunOptions, run_scene

    run = run_scene(tiny, tmp_path / "run", RunOptions(config="tri-I", baseline=True, progress=False))
    poses = read_poses(run / "poses.csv")
    meta = json.loads((run / "run.json").read_text())
    assert meta["method"] == "baseline" and meta["cameras"] == ["c0", "c1", "c2"]
    assert meta["scene_fingerprint"] == tiny.fingerprint()
    # independent computation
    by_key: dict[tuple[int, int], list[np.ndarray]] = {}
    heights = {c.id: c.default_height for c in tiny.classes}
    for cam in ("c0", "c1", "c2"):
        t = read_mots(tiny.masks_path(cam))
        uv = mask_centers(t.rles, t.height, t.width, "bbox")
        X, _ = normal_positions(tiny.cameras[cam], tiny.ground, uv,
                                np.array([heights[c] for c in t.class_id]))
        for f, tid, x in zip(t.frame, t.track_id, X):
            by_key.setdefault((int(f), int(tid)), []).append(x[:2])
    assert len(poses) == len(by_key)
    for i in range(len(poses)):
        want = np.mean(by_key[(int(poses.frame[i]), int(poses.track_id[i]))], axis=0)
        np.testing.assert_allclose(poses.xyz[i, :2], want, atol=1e-9)
    np.testing.assert_allclose(poses.xyz[:, 2], 0.0, atol=1e-9)  # flat ground
    # views.csv: one row per detection per view, zero residuals
    v = read_views(run / "views.csv")
    assert len(v.frame) == sum(len(x) for x in by_key.values())
    assert np.all(v.residual == 0)
    # sizes from the scene's class sizes; headings follow the straight tracks
    car = poses.cls == "car"
    np.testing.assert_allclose(poses.size[car], np.tile(SIZES["car"], (car.sum(), 1)))


def test_headings_follow_motion_on_truth(tiny):
    """Sanity of the heading stage on exact positions: the truth tracks are straight lines, so
    eq. (2) gives their heading exactly from the second frame on."""
    from seg2pose.geometry.normal import headings_from_tracks

    gt = read_poses(tiny.gt_path)
    h = headings_from_tracks(gt.track_id, gt.frame, gt.xyz[:, :2])
    ok = np.isfinite(h)
    d = np.angle(np.exp(1j * (h[ok] - gt.heading[ok])))
    np.testing.assert_allclose(d, 0, atol=1e-9)


def test_run_refuses_overwrite_and_missing_models(tiny, tmp_path):
    from seg2pose.method.pipeline import RunOptions, run_scene

    run = run_scene(tiny, tmp_path / "r", RunOptions(config="mono-1", baseline=True, progress=False))
    with pytest.raises(S2PError, match="--force"):
        run_scene(tiny, run, RunOptions(config="mono-1", baseline=True, progress=False))
    run_scene(tiny, run, RunOptions(config="mono-1", baseline=True, force=True, progress=False))
    with pytest.raises(S2PError, match="no Seg2PoseNet model"):
        run_scene(tiny, tmp_path / "r2", RunOptions(config="mono-1", models_dir=tmp_path / "none",
                  progress=False))
    with pytest.raises(InputError, match="unknown configuration"):
        run_scene(tiny, tmp_path / "r3", RunOptions(config="nope", baseline=True, progress=False))


def test_split_and_lockstep_streaming(tiny, tmp_path):
    from seg2pose.method.pipeline import RunOptions, iter_frames, run_scene

    frames = [f for f, _ in iter_frames(tiny, ["c0", "c1", "c2"], (5, 9))]
    assert frames == [5, 6, 7, 8, 9]
    run = run_scene(tiny, tmp_path / "r", RunOptions(config="stereo-20", baseline=True, split="test",
                    progress=False))
    poses = read_poses(run / "poses.csv")
    a, b = tiny.splits["test"]
    assert poses.frame.min() >= a and poses.frame.max() <= b


def test_eval_equals_hand_computation(tmp_path):
    """Toy case: two frames, two road users, errors 3-4-5 and 0.5 m; distances 2 and 7 m
    from the rig centre, so bins [0, 5) and [5, 10) hold one error each."""
    from seg2pose.eval.paper_table import evaluate_run

    scene = make_tiny_scene(tmp_path / "s", frames=4, n_users=1)
    origin = scene.rig.center[:2]
    gt = PoseTable([0, 0], [1, 2], np.array(["car", "pedestrian"], object),
                   [[origin[0] + 2, origin[1], 0], [origin[0] + 7, origin[1], 0]], [0, 0],
                   [[4, 2, 1.5], [0.6, 0.6, 1.8]])
    write_poses(scene.gt_path, gt)
    est = PoseTable([0, 0, 1], [1, 2, 9], np.array(["car", "pedestrian", "car"], object),
                    [[origin[0] + 5, origin[1] + 4, 0], [origin[0] + 7.5, origin[1], 0], [0, 0, 0]],
                    [0, 0, 0], [[4, 2, 1.5]] * 3)
    (tmp_path / "run").mkdir()
    write_poses(tmp_path / "run" / "poses.csv", est)
    (tmp_path / "run" / "run.json").write_text(json.dumps({"scene_fingerprint": scene.fingerprint()}))
    res = evaluate_run(scene, tmp_path / "run")
    assert res.n_matched == 2
    assert res.mean_error == pytest.approx((5.0 + 0.5) / 2)
    assert res.per_class == pytest.approx({"car": 5.0, "pedestrian": 0.5})
    assert [(lo, hi, n) for lo, hi, n, _ in res.bins] == [(0, 5, 1), (5, 10, 1)]
    assert [m for *_, m in res.bins] == pytest.approx([5.0, 0.5])


def test_paper_table_baseline_only(tiny, tmp_path):
    from seg2pose.eval.paper_table import paper_table
    from seg2pose.method.pipeline import RunOptions, run_scene

    out, text = paper_table(tiny, out_dir=tmp_path / "pt", baseline_only=True, progress=False)
    d = json.loads((out / "results.json").read_text())
    assert set(d["results"]) == {"mono-1 baseline", "stereo-20 baseline", "tri-I baseline"}
    assert (out / "error_vs_distance.png").stat().st_size > 1000
    assert "tri-I baseline" in text
    # views computed once and fused per configuration = a direct run of that configuration
    direct = run_scene(tiny, tmp_path / "direct", RunOptions(config="stereo-20", baseline=True,
                       split="test", progress=False))
    a = read_poses(direct / "poses.csv")
    b = read_poses(out / "runs" / "stereo-20-baseline" / "poses.csv")
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.track_id, b.track_id)
    with pytest.raises(S2PError):
        paper_table(tiny, out_dir=tmp_path / "pt", baseline_only=True, progress=False)
