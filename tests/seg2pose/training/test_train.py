"""Training on a tiny scene: validation loss goes down, checkpoints resume, bad input is refused,
and the trained models run through the pipeline."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene, s2p, tiny_config, tiny_train_scene

from seg2pose.core.errors import S2PError

tiny = pytest.fixture(scope="module")(tiny_train_scene)


def _val_loss_untrained(scene, cam):
    """Validation loss of a freshly initialised net (seed 0), computed like train.py does."""
    from seg2pose.io.poses import read_poses
    from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet
    from seg2pose.training.examples import annotated_examples
    from seg2pose.training.train import TrainData, _evaluate

    torch.manual_seed(0)
    net = Seg2PoseNet(NetConfig.lite(n_classes=3))
    gt = read_poses(scene.gt_path)
    val = annotated_examples(scene, cam, gt, "val", 420, 3)
    c = scene.cameras[cam]
    norm = Normalisation.for_scene(scene.ground_points, c.width, c.height)
    return _evaluate(net, TrainData.of(val, norm, ["pedestrian", "bicyclist", "car"], True),
                     torch.device("cpu"), 1.0)


def test_training_lowers_validation_loss_and_resumes(tiny, tmp_path, fake_rough):
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.training.train import train_scene

    before, before_m = _val_loss_untrained(tiny, "c1")
    out = train_scene(tiny, tmp_path / "models", tiny_config(), cameras=["c1"], progress=False)
    path = out / "c1__all.safetensors"
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["complete"] is True and meta["camera"] == "c1" and meta["arch"] == "lite"
    assert meta["scene_fingerprint"] == tiny.fingerprint()
    assert meta["classes"] == ["pedestrian", "bicyclist", "car"]
    assert meta["val_loss"] < 0.7 * before, (meta["val_loss"], before)
    assert not path.with_name(path.name + ".state.pt").exists()
    # a finished model is kept (not retrained) on a second call
    mtime = path.stat().st_mtime_ns
    train_scene(tiny, out, tiny_config(), cameras=["c1"], progress=False)
    assert path.stat().st_mtime_ns == mtime
    ck = Checkpoint.load(path, arch="lite", camera="c1")
    assert ck.info["val_loss"] == pytest.approx(meta["val_loss"])


def test_resume_after_interruption(tiny, tmp_path, fake_rough, monkeypatch):
    """Interrupt after epoch 3 of 6, train again: it resumes at epoch 4 and ends complete."""
    import seg2pose.training.train as T

    calls = {"n": 0}
    real = T._evaluate

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(T, "_evaluate", flaky)
    cfg = tiny_config(epochs=6, batches_per_epoch=4)
    with pytest.raises(KeyboardInterrupt):
        T.train_scene(tiny, tmp_path / "m", cfg, cameras=["c0"], progress=False)
    path = tmp_path / "m" / "c0__all.safetensors"
    state = torch.load(path.with_name(path.name + ".state.pt"), weights_only=False)
    assert state["epoch"] == 3 and state["run"] == 0
    assert json.loads(path.with_suffix(".json").read_text())["complete"] is False
    monkeypatch.setattr(T, "_evaluate", real)
    calls["n"] = 0
    T.train_scene(tiny, tmp_path / "m", cfg, cameras=["c0"], progress=False)
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["complete"] is True and 1 <= meta["epoch"] <= 6


def test_nan_loss_stops_and_keeps_best(tiny, tmp_path, fake_rough, monkeypatch):
    import seg2pose.training.train as T

    real = T._evaluate
    calls = {"n": 0}

    def nan_later(*a, **k):
        calls["n"] += 1
        return (float("nan"), float("nan")) if calls["n"] >= 2 else real(*a, **k)

    monkeypatch.setattr(T, "_evaluate", nan_later)
    with pytest.raises(S2PError, match="nan"):
        T.train_scene(tiny, tmp_path / "m", tiny_config(epochs=3, batches_per_epoch=2),
                      cameras=["c2"], progress=False)
    path = tmp_path / "m" / "c2__all.safetensors"
    assert path.exists()  # the epoch-1 checkpoint is kept
    assert json.loads(path.with_suffix(".json").read_text())["epoch"] == 1


def test_no_ground_truth_needs_zero_annotation(tmp_path, fake_rough):
    from seg2pose.io.scene import load_scene
    from seg2pose.training.train import train_scene

    root = tmp_path / "s"
    make_tiny_scene(root, frames=8, n_users=3)
    shutil.rmtree(root / "gt")
    scene = load_scene(root)
    with pytest.raises(S2PError, match="zero-annotation"):
        train_scene(scene, tmp_path / "m", tiny_config(), cameras=["c1"], progress=False)
    out = train_scene(scene, tmp_path / "m", tiny_config(zero_annotation=True, epochs=2,
                                                         batches_per_epoch=3),
                      cameras=["c1"], progress=False)
    meta = json.loads((out / "c1__all.json").read_text())
    assert meta["zero_annotation"] is True and meta["n_train"] == 0 and meta["n_rough"] == 72
    # radial calibration from the unlabelled train-split masks (no ground truth exists here)
    assert set(meta["radial_offset"]) == {"pedestrian", "bicyclist", "car"}


def test_trained_models_in_pipeline(tiny, tmp_path, fake_rough):
    """Per-class models (the paper's layout) for one camera run through `s2p run`; views.csv
    holds the residuals, and poses = normal position + residual (one view)."""
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_views
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.training.train import train_scene

    out = train_scene(tiny, tmp_path / "m", tiny_config(share_classes=False, epochs=1,
                                                        batches_per_epoch=2),
                      cameras=["c1"], progress=False)
    assert sorted(p.name for p in out.glob("*.safetensors")) == [
        "c1__bicyclist.safetensors", "c1__car.safetensors", "c1__pedestrian.safetensors"]
    run = run_scene(tiny, tmp_path / "run", RunOptions(config="mono-1", models_dir=out, split="test",
                    progress=False))
    v = read_views(run / "views.csv")
    assert np.abs(v.residual).max() > 0 and np.abs(v.residual).max() <= 2.5
    p = read_poses(run / "poses.csv")
    est = v.normal[:, :2] + v.residual
    order = np.lexsort((v.track_id, v.frame))
    np.testing.assert_allclose(p.xyz[:, :2], est[order], atol=1e-6)
    with pytest.raises(S2PError, match="arch"):
        run_scene(tiny, tmp_path / "run2", RunOptions(config="mono-1", models_dir=out, arch="paper",
                  progress=False))


def test_geometry_model_trains_and_runs_with_the_same_features(tiny, tmp_path, fake_rough):
    """--geometry: the net's vector gains the 14 mask-geometry features; the pipeline computes
    them for each detection exactly as the training examples had them (same mask -> same
    features), and a geometry model refuses to predict without them."""
    from seg2pose.io.mots import read_mots
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_views
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.method.features import N_GEO, scene_geometry
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.training.examples import annotated_examples
    from seg2pose.training.train import train_scene

    out = train_scene(tiny, tmp_path / "m", tiny_config(geometry=True, epochs=2), cameras=["c1"],
                      progress=False)
    ck = Checkpoint.load(out / "c1__all.safetensors")
    assert ck.net.cfg.n_geo == N_GEO and ck.info["geometry"] == "geo1"
    ex = annotated_examples(tiny, "c1", read_poses(tiny.gt_path), "test", 420, 3)
    assert np.abs(ex.geo).sum() > 0
    run = run_scene(tiny, tmp_path / "run", RunOptions(config="mono-1", models_dir=out, split="test",
                    progress=False))
    v = read_views(run / "views.csv")
    # the pipeline's normal positions and centres for the matched masks equal the examples'
    m = read_mots(tiny.masks_path("c1"))
    keys = [(round(u, 6), round(w, 6)) for u, w in v.uv]
    rows = {k: i for i, k in enumerate(keys)}
    once = {k for k in keys if keys.count(k) == 1}  # masks with a unique centre, to pair them
    sel = [j for j, (u, w) in enumerate(ex.centers) if (round(u, 6), round(w, 6)) in once]
    assert len(sel) > 0.8 * len(ex)
    ex = ex.take(np.array(sel))
    hit = [rows[(round(u, 6), round(w, 6))] for u, w in ex.centers]
    np.testing.assert_allclose(v.normal[hit, :2], ex.normal, atol=1e-9)
    fr = {k: i for i, k in enumerate(zip(m.frame, m.track_id))}
    idx = [fr[(v.frame[h], v.track_id[h])] for h in hit]
    geo = scene_geometry(tiny, "c1", [m.rles[i] for i in idx], m.height, m.width,
                         v.uv[hit], v.normal[hit, :2], ex.cls)
    np.testing.assert_array_equal(geo, ex.geo)
    assert np.abs(v.residual).max() > 0
    with pytest.raises(S2PError, match="mask-geometry"):
        ck.predict(np.zeros((1, 420, 420), np.uint8), np.zeros((1, 2)), np.zeros((1, 2)),
                   np.array(["car"]))


def test_ensemble_of_model_folders_averages_the_residuals(tiny, tmp_path, fake_rough):
    """`s2p run --models A --models B`: each view's residual is the mean of A's and B's."""
    from seg2pose.io.run import read_views
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.training.train import train_scene

    a = train_scene(tiny, tmp_path / "a", tiny_config(epochs=1, batches_per_epoch=3), cameras=["c1"],
                    progress=False)
    b = train_scene(tiny, tmp_path / "b", tiny_config(epochs=1, batches_per_epoch=3, seed=7,
                                                      geometry=True), cameras=["c1"], progress=False)
    runs = {k: read_views(run_scene(tiny, tmp_path / f"run_{k}", RunOptions(config="mono-1", models_dir=m,
                                    split="test", progress=False)) / "views.csv")
            for k, m in (("a", a), ("b", b), ("ab", [a, b]))}
    ra, rb, rab = (runs[k].residual for k in ("a", "b", "ab"))
    assert np.abs(ra - rb).max() > 1e-3
    np.testing.assert_allclose(rab, (ra + rb) / 2, atol=1e-6)
    meta = json.loads((tmp_path / "run_ab" / "run.json").read_text())
    # run.json: checkpoint paths relative to the run folder, with their file names and digests
    from seg2pose.core.digest import file_sha256

    entry = meta["models"]["c1/car"]
    assert [(tmp_path / "run_ab" / p).resolve() for p in entry["path"]] == \
        [(a / "c1__all.safetensors").resolve(), (b / "c1__all.safetensors").resolve()]
    assert entry["path"] == ["../a/c1__all.safetensors", "../b/c1__all.safetensors"]
    assert entry["file"] == ["c1__all.safetensors"] * 2
    assert entry["sha256"] == [file_sha256(a / "c1__all.safetensors"), file_sha256(b / "c1__all.safetensors")]


def test_cli_train_resumes_with_other_run_time_settings(tiny, tmp_path, fake_rough, monkeypatch, capsys):
    """An interrupted ``s2p train`` run again with another ``--threads`` continues where it
    stopped (the run-time settings are not part of the protocol) instead of starting afresh."""
    import seg2pose.training.train as T

    calls = {"n": 0}
    real = T._evaluate

    def counted(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3 and not calls.get("resumed"):
            raise KeyboardInterrupt  # in epoch 3 of 4: the resume state holds epochs 1-2
        return real(*a, **k)

    monkeypatch.setattr(T, "_evaluate", counted)
    argv = ["train", tiny.root, "-o", tmp_path / "m", "--protocol", "demo", "--epochs", "4",
            "--batches", "2", "--camera", "c0", "--rough", "24"]
    code, _, err = s2p(monkeypatch, capsys, *argv, "--threads", "2")
    assert code == 130 and "interrupted" in err
    state = torch.load(next((tmp_path / "m").glob("*.state.pt")), weights_only=False)
    assert state["epoch"] == 2 and state["config"]["threads"] == 2
    calls.update(n=0, resumed=True)
    code, _, err = s2p(monkeypatch, capsys, *argv, "--threads", "1")
    assert code == 0, err
    assert "resuming" in err and "at run 1, epoch 3" in err and "afresh" not in err
    assert calls["n"] == 2  # epochs 3 and 4 only
    meta = json.loads(next((tmp_path / "m").glob("*.json")).read_text())
    assert meta["complete"] is True and meta["train_config"]["threads"] == 1


def test_long_protocol_is_quick_for_longer_with_a_quarter_rough():
    """``--protocol long`` = ``--protocol quick --epochs 60 --rough-every 4``: models trained
    either way are of one protocol (a finished one is skipped, a stopped one resumed), and
    not of quick's."""
    from seg2pose.training.config import TrainConfig, TrainSettings, same_protocol, training_record

    flags = TrainConfig.quick().replace(epochs=60, rough_every=4)
    assert TrainConfig.long() == flags
    assert same_protocol(training_record(flags, TrainSettings(threads=1)), TrainConfig.long())
    assert not same_protocol(training_record(TrainConfig.quick(), TrainSettings()), TrainConfig.long())
