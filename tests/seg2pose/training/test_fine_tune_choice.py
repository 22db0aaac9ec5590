"""The per-class choice of ``s2p train --from`` (seg2pose.training.fine_tune_choice): scores
per road user, folds by road user, the choice with hand-made errors, and end to end a start so
wrong that the baseline must win: the folder's marker, then ``s2p run`` using the normal
positions for that class and the model for the others."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene

from seg2pose.io.poses import PoseTable, read_poses, write_poses
from seg2pose.training.examples import ExampleSet
from seg2pose.training.fine_tune_choice import choose, per_user_mean, road_user_folds
from seg2pose.training.fine_tune_data import WeightedExamples


def test_per_user_mean_counts_each_road_user_once():
    # user 1: 1, 1, 1, 1 (mean 1); user 2: 3 (mean 3) -> 2, not the example mean 7/5
    err = np.array([1.0, 1.0, 3.0, 1.0, 1.0])
    users = np.array([1, 1, 2, 1, 1])
    assert per_user_mean(err, users) == pytest.approx(2.0)
    assert per_user_mean(np.array([np.nan, 2.0]), np.array([1, 2])) == pytest.approx(2.0)
    assert np.isnan(per_user_mean(np.array([np.nan]), np.array([1])))


@pytest.mark.parametrize("n, k", [(1, 3), (2, 3), (5, 3), (7, 2), (4, 4)])
def test_folds_partition_the_road_users(n, k):
    users = np.repeat(np.arange(10, 10 + n), 3)
    folds = road_user_folds(users, k, seed=1)
    assert len(folds) == min(n, k)
    flat = np.concatenate(folds)
    assert sorted(flat.tolist()) == list(range(10, 10 + n))  # each road user in exactly one fold
    sizes = [len(f) for f in folds]
    assert max(sizes) - min(sizes) <= 1


def _w(cls, users):
    ex = ExampleSet.empty(4, 1).take(np.zeros(0, np.int64))
    ex.cls = np.asarray(cls, object)
    n = len(ex.cls)
    return WeightedExamples(ex, np.ones(n), np.asarray(users, np.int64), np.zeros(n))


def test_choose_per_class_with_hand_made_errors():
    # car: users 1, 2; pedestrian: users 3, 4; bicyclist: user 5 only (nothing validates)
    w = _w(["car", "car", "car", "pedestrian", "pedestrian", "bicyclist"], [1, 1, 2, 3, 4, 5])
    nan = np.nan
    errors = {"baseline": np.array([0.2, 0.2, 0.2, 1.0, 1.0, 0.5]),
              "start": np.array([0.5, 0.5, 0.5, 0.8, 0.8, 0.4]),
              "fine-tuned": np.array([0.4, 0.4, 0.4, 0.3, 0.5, nan])}
    ch = choose(errors, w, ["pedestrian", "bicyclist", "car"])
    # one network: fine-tuned (0.4 + 0.4) beats start (0.5 + 0.8) on the validated classes
    assert ch.net == "fine-tuned"
    # car: baseline 0.2 < fine-tuned 0.4 -> baseline; pedestrian: 0.4 < 1.0 -> the network;
    # bicyclist (not validated): the start's 0.4 < 0.5 -> the network
    assert ch.baseline == ["car"]
    assert [ch.chosen(c) for c in ("car", "pedestrian", "bicyclist")] == ["baseline", "fine-tuned",
                                                                         "fine-tuned"]
    assert ch.scores["pedestrian"]["fine-tuned"] == pytest.approx(0.4)
    assert "car: baseline (2 road user(s): baseline 0.200 m, start 0.500 m, fine-tuned 0.400 m)" == \
        ch.describe("car")


def test_choose_ties_go_to_the_simpler_and_one_road_user_is_unvalidated():
    w = _w(["car", "car"], [1, 2])
    same = np.array([0.3, 0.3])
    ch = choose({"baseline": same, "start": same, "fine-tuned": same}, w, ["car"])
    assert ch.net == "start" and ch.baseline == ["car"]
    one = _w(["car"], [7])
    ch = choose({"baseline": np.array([0.6]), "start": np.array([0.2]), "fine-tuned": np.array([np.nan])},
                one, ["car"])
    assert ch.net == "fine-tuned" and ch.unvalidated == ["car"] and ch.baseline == []
    assert "fine-tuned unvalidated (one road user)" in ch.describe("car")
    # the baseline better on the one road user: the start stays (a switch needs two road users)
    worse = {"baseline": np.array([0.2]), "start": np.array([0.6]), "fine-tuned": np.array([np.nan])}
    ch = choose(worse, one, ["car"])
    assert ch.baseline == [] and ch.unvalidated == [] and ch.net == "start"
    ch = choose(worse, one, ["car"], baseline_min_users=1)
    assert ch.baseline == ["car"] and ch.unvalidated == []


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("ftc") / "scene"
    make_tiny_scene(root, frames=40, n_users=9, seed=3)
    gt = read_poses(root / "gt" / "poses.csv")
    src = np.where(gt.frame % 5 == 0, "keyframe", "interpolated").astype(object)
    write_poses(root / "gt" / "poses.csv", PoseTable(gt.frame, gt.track_id, gt.cls, gt.xyz,
                                                     gt.heading, gt.size, src))
    from seg2pose.io.scene import load_scene

    return load_scene(root)


def _opts(**kw):
    from seg2pose.training.fine_tune import FineTuneOptions

    return FineTuneOptions(**{**dict(epochs=1, batches_per_epoch=2, batch_size=8, rough_per_class=8,
                                     lr=1e-3, threads=1, progress=False), **kw})


def test_a_start_far_off_for_cars_gives_cars_the_baseline_in_run(scene, tmp_path, fake_rough):
    """A car start whose output is pinned at +2.5 m in x and y (zero weights, a large bias:
    2.5 tanh saturates) is at least 3.5 - 2.5 = 1 m off on every example whose truth is within
    2.5 m of its normal position, more than the baseline on the tiny scene's clean masks: cars
    take the baseline (a marker, no model file), and ``s2p run`` uses normal positions for
    cars (residual 0) and the models for the other classes."""
    from seg2pose.method.checkpoint import Checkpoint, load_models
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.training.fine_tune import fine_tune_scene
    from seg2pose.training.fine_tune_data import scratch_start

    start = tmp_path / "start"
    scratch_start(scene, start, arch="lite", geometry=False)
    car = Checkpoint.load(start / "all__car.safetensors")
    with torch.no_grad():
        car.net.out.weight.zero_()
        car.net.out.bias.fill_(50.0)
    car.save(start / "all__car.safetensors")
    out = tmp_path / "out"
    res = fine_tune_scene(scene, start, out, _opts(), cameras=["c1"])
    assert res.lines["all__car.safetensors"].startswith("all__car: baseline chosen (car: baseline (")
    marker = json.loads((out / "all__car.baseline.json").read_text())
    assert marker["scores_m"]["baseline"] < 1.0 <= marker["scores_m"]["start"]
    assert not (out / "all__car.safetensors").exists()
    ms = load_models(scene, ["c1"], out)
    # the other classes: whatever their lines say (on the tiny scene's clean masks the
    # baseline is hard to beat for pedestrians)
    served = {c for c in ("pedestrian", "bicyclist")
              if "baseline chosen" not in res.lines[f"all__{c}.safetensors"]}
    assert served  # the bicyclists' start beats their baseline
    assert sorted(ms.chosen_baseline) == sorted(("c1", c) for c in {"pedestrian", "bicyclist", "car"} - served)
    assert ("c1", "car") in ms.fallback and {k[1] for k in ms.models} == served
    run = run_scene(scene, tmp_path / "run", RunOptions(config="mono-1", models_dir=out,
                                                        progress=False, force=True))
    from seg2pose.io.run import read_views

    v = read_views(run / "views.csv")
    is_car, is_served = v.cls == "car", np.isin(v.cls, list(served))
    assert is_car.any() and is_served.any()
    assert np.all(v.residual[is_car] == 0) and np.any(v.residual[is_served] != 0)
    assert "c1/car" in json.loads((run / "run.json").read_text())["baseline_fallback"]
    # the fine-tuned folder as the start of another fine-tuning: the baseline's marker stands
    res = fine_tune_scene(scene, out, tmp_path / "again", _opts(choose=False, lr=0.0), cameras=["c1"])
    assert res.lines["all__car.baseline.json"] == ("all__car.baseline.json: the start runs the baseline "
                                                   "here; its marker is kept")
    assert ("c1", "car") in load_models(scene, ["c1"], tmp_path / "again").chosen_baseline
    # fine-tuned again without the choice: the stale marker goes, the model comes back
    res = fine_tune_scene(scene, start, out, _opts(choose=False), cameras=["c1"], classes=["car"])
    assert res.lines["all__car.safetensors"].startswith("all__car: fine-tuned, epoch 1 of 1")
    assert not (out / "all__car.baseline.json").exists() and (out / "all__car.safetensors").exists()
    assert ("c1", "car") not in load_models(scene, ["c1"], out).chosen_baseline


def test_truth_box_iou_by_hand():
    """The projected box's own bounding box has IoU 1; shifted right by half its width the
    overlap is half of each, IoU = 0.5 / 1.5 = 1/3; a road user behind the camera scores 0."""
    from seg2pose.geometry.camera import Camera
    from seg2pose.training.fine_tune_data import truth_box_iou

    cam = Camera.look_at("c", np.array([0.0, 0.0, 6.0]), np.array([15.0, 0.0, 0.0]), 800.0, 1280, 720)
    xyz = np.array([[15.0, 1.0, 0.0], [-10.0, 0.0, 0.0]])
    size = np.array([[4.5, 1.8, 1.5], [4.5, 1.8, 1.5]])
    heading = np.array([0.3, np.nan])
    # the first box's projection, its corners written out: its bounding box
    c, s = np.cos(0.3), np.sin(0.3)
    pts = [[15 + c * dx - s * dy, 1 + s * dx + c * dy, z] for dx in (-2.25, 2.25) for dy in (-0.9, 0.9)
           for z in (0.0, 1.5)]
    uv = cam.project_points(np.array(pts))[0]
    box = np.array([*uv.min(axis=0), *uv.max(axis=0)])
    w = box[2] - box[0]
    shifted = box + np.array([w / 2, 0, w / 2, 0])
    got = truth_box_iou(cam, xyz, heading, size, np.stack([box, box]))
    assert got[0] == pytest.approx(1.0) and got[1] == 0.0
    assert truth_box_iou(cam, xyz[:1], heading[:1], size[:1], shifted[None])[0] == pytest.approx(1 / 3)


def test_masks_below_the_iou_floor_are_never_drawn(scene):
    from seg2pose.training.fine_tune_data import annotated_masks, usable_rows, weighted_examples

    gt = usable_rows(read_poses(scene.gt_path), scene)
    ann = annotated_masks(scene, "c1", gt.take(np.argsort(gt.frame, kind="stable")))
    assert len(ann.iou) == len(ann.rles) and ((ann.iou > 0.3) & (ann.iou <= 1)).mean() > 0.9
    floor = float(np.median(ann.iou))
    every = weighted_examples(scene, ann, 420, 3)
    some = weighted_examples(scene, ann, 420, 3, min_iou=floor)
    assert (every.weight > 0).all() and len(some.ex) == len(every.ex)
    # the masks below the median IoU: about half, weight 0 (kept for the comparison)
    assert (some.weight == 0).sum() == (ann.iou < floor).sum()
    assert sorted(some.baseline_error.round(9)) == sorted(every.baseline_error.round(9))
