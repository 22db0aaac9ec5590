"""Self-training of zero-annotation models (seg2pose.training.self_training): pseudo poses are
the smoothed (fused) estimates, ground truth is never read, the fine-tuning starts from the
rough-only weights and says so in the checkpoint, finished models are skipped."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene, s2p, tiny_config

from seg2pose.core.errors import S2PError
from seg2pose.io.run import ViewTable


def _views(frames, tids, cams, xy) -> ViewTable:
    n = len(frames)
    normal = np.column_stack([xy, np.zeros(n)])
    return ViewTable(np.asarray(frames), np.asarray(tids), np.asarray(cams, object),
                     np.full(n, "car", object), np.zeros((n, 2)), normal, np.zeros((n, 2)))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_tiny_scene(tmp_path_factory.mktemp("self"), frames=24, n_users=3, seed=2)


def test_track_pseudo_poses_are_each_lens_smoothed_by_hand(scene):
    """One lens, one track, x = f + 0.1 (-1)^f: a centred line over +-1 frame is the mean of
    three values inside (f - 0.1 (-1)^f / 3) and the value itself at the ends (a line through
    two points); the other lens's views of the same track are smoothed on their own."""
    from seg2pose.training.self_training import pseudo_poses

    f = np.arange(6)
    x = f + 0.1 * (-1.0) ** f
    v = _views(np.r_[f, f], np.full(12, 5), ["c0"] * 6 + ["c1"] * 6,
               np.column_stack([np.r_[x, x + 1.0], np.full(12, 12.0)]))
    lab = pseudo_poses(scene, v, "track", smooth=1)
    want = f - 0.1 * (-1.0) ** f / 3
    want[[0, -1]] = x[[0, -1]]
    got0 = lab.lookup("c0", f, np.full(6, 5))
    got1 = lab.lookup("c1", f, np.full(6, 5))
    np.testing.assert_allclose(got0[:, 0], want, atol=1e-12)
    np.testing.assert_allclose(got1[:, 0], want + 1.0, atol=1e-12)
    np.testing.assert_allclose(got0[:, 1], 12.0, atol=1e-12)
    # untracked views (id -1) and views of another frame get no pseudo pose
    assert np.isnan(lab.lookup("c0", np.array([2, 99]), np.array([-1, 5]))).all()


def test_views_pseudo_poses_equal_smoothed_fused_poses_at_track_heights(scene):
    """"views": for every tracked view, the pose the pipeline fuses over the lenses at the
    fitted per-track heights, smoothed along the track -- exactly; the same for all lenses;
    "fused": likewise at the default heights."""
    from seg2pose.method.fusion import fuse
    from seg2pose.method.pipeline import compute_views
    from seg2pose.method.track_heights import apply_track_heights
    from seg2pose.training.self_training import pseudo_poses

    views, _ = compute_views(scene, ["c0", "c1", "c2"], scene.split_range("train"), None,
                             progress=False)
    lab = pseudo_poses(scene, views, "views", smooth=3)
    poses = fuse(apply_track_heights(scene, views)[0], scene, smooth=3)
    assert len(lab) == int((views.track_id >= 0).sum()) > 0
    fused = pseudo_poses(scene, views, "fused", smooth=3)
    plain = fuse(views, scene, smooth=3)  # "fused": the same at the default heights
    for cam in ("c0", "c1", "c2"):
        for lab_, poses_ in ((lab, poses), (fused, plain)):
            got = lab_.lookup(cam, poses_.frame, poses_.track_id)
            seen = np.isfinite(got[:, 0])
            assert seen.sum() > 10
            np.testing.assert_array_equal(got[seen], poses_.xyz[seen, :2])
    assert not np.array_equal(lab.xy, fused.xy)  # the fitted heights moved some tracks


def test_unknown_flavour_and_self_training_without_zero_annotation_are_refused():
    from seg2pose.training.config import TrainConfig

    with pytest.raises(S2PError, match="unknown self_train 'smoothed'"):
        TrainConfig(zero_annotation=True, self_train="smoothed")
    with pytest.raises(S2PError, match="zero-annotation"):
        TrainConfig(self_train="views")


def _train(scene, out, **kw):
    from seg2pose.training.self_training import train_self_trained

    cfg = tiny_config(zero_annotation=True, epochs=2, batches_per_epoch=3, self_train="views",
                      self_epochs=1, **kw)
    return train_self_trained(scene, out, cfg, progress=False)


def test_self_training_never_reads_ground_truth(tmp_path, fake_rough, monkeypatch):
    """The pseudo poses of a scene without gt/poses.csv are those of the same scene with it,
    and the training's reading of the truth fails the test."""
    from seg2pose.io.scene import load_scene
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.training import self_training as st

    a, b = tmp_path / "a", tmp_path / "b"
    make_tiny_scene(a, frames=24, n_users=3, seed=2)
    shutil.copytree(a, b)
    (b / "gt" / "poses.csv").unlink()

    def no_truth(*args, **kw):
        raise AssertionError("ground truth read")

    # (patched where training imported it: patching seg2pose.io.poses itself would leak into
    # modules first imported during this test)
    monkeypatch.setattr("seg2pose.training.train.read_poses", no_truth)
    labels = {}
    for root in (a, b):
        scene = load_scene(root)
        out = _train(scene, root / "m")
        views = st.rough_stage_views(scene, out / "rough-stage", ["c0", "c1", "c2"], False)
        labels[root.name] = st.pseudo_poses(scene, views, "views", 4)
        assert Checkpoint.load(out / "c1__all.safetensors").info["complete"]
    for k in ("camera", "frame", "track_id", "xy"):
        np.testing.assert_array_equal(getattr(labels["a"], k), getattr(labels["b"], k))


def test_fine_tuning_starts_from_the_rough_only_weights(tmp_path, fake_rough, capsys):
    """With a learning rate of 0 the fine-tuned net is the rough-only net, weight for weight;
    it carries no radial offset (its targets include it) and records its self-training; a
    second call skips the finished models."""
    from seg2pose.method.checkpoint import Checkpoint

    root = tmp_path / "s"
    scene = make_tiny_scene(root, frames=24, n_users=3, seed=2)
    out = _train(scene, tmp_path / "m", lr=0.0)
    for cam in ("c0", "c1", "c2"):
        ft = Checkpoint.load(out / f"{cam}__all.safetensors")
        start = Checkpoint.load(out / "rough-stage" / f"{cam}__all.safetensors")
        for k, w in start.net.state_dict().items():
            assert torch.equal(w, ft.net.state_dict()[k]), k
        assert "radial_offset" in start.info and "radial_offset" not in ft.info
        st = ft.info["self_training"]
        assert st["flavour"] == "views" and st["epochs"] == 1 and st["split"] == "train"
        assert st["start"]["radial_offset"] == start.info["radial_offset"]
        assert ft.info["train_config"]["self_train"] == "views" and ft.info["n_train"] > 0
        assert ft.info["train_config"]["lr"] == 0.0
    before = (out / "c1__all.safetensors").stat().st_mtime_ns
    capsys.readouterr()
    _train(scene, tmp_path / "m", lr=0.0)
    assert (out / "c1__all.safetensors").stat().st_mtime_ns == before
    assert "done already" in capsys.readouterr().err
    # the run on the train split is kept beside the rough-only models (and reused)
    meta = json.loads((out / "rough-stage" / "train-run" / "run.json").read_text())
    assert meta["split"] == "train" and meta["method"] == "seg2posenet"


def test_rough_stage_of_another_protocol_is_refused(tmp_path, fake_rough):
    root = tmp_path / "s"
    scene = make_tiny_scene(root, frames=24, n_users=3, seed=2)
    from seg2pose.training.train import train_scene

    # rough-only models of another protocol (3 epochs) copied in as the first stage
    train_scene(scene, tmp_path / "m" / "rough-stage",
                tiny_config(zero_annotation=True, epochs=3, batches_per_epoch=3), progress=False)
    with pytest.raises(S2PError, match="not a finished rough-only model of this protocol"):
        _train(scene, tmp_path / "m")


def test_cli_self_train_option(tmp_path, monkeypatch, capsys):
    root = tmp_path / "s"
    make_tiny_scene(root, frames=8, n_users=2)
    code, _, err = s2p(monkeypatch, capsys, "train", root, "--self-train", "views")
    assert code == 2 and "add --zero-annotation" in err and "Traceback" not in err
    code, _, err = s2p(monkeypatch, capsys, "train", root, "--zero-annotation", "--self-train", "x")
    assert code == 2 and "unknown self_train 'x'" in err
    code, out, _ = s2p(monkeypatch, capsys, "train", "--help")
    assert "--self-train" in out and "--self-epochs" in out


def test_pseudo_poses_come_from_the_train_split_or_all_frames(scene, tmp_path):
    from seg2pose.training.self_training import unlabelled_split

    assert unlabelled_split(scene) == "train"
    assert unlabelled_split(make_tiny_scene(tmp_path / "nosplits", frames=4, n_users=1,
                                            splits={})) is None


def test_a_lens_without_pseudo_poses_gives_no_examples(scene):
    from seg2pose.training.self_training import PseudoLabels, pseudo_examples

    none = PseudoLabels(np.zeros(0, object), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros((0, 2)))
    tr, va = pseudo_examples(scene, "c0", none, ["car"], np.zeros(0), 420, 3, "centroid", 10,
                             np.random.default_rng(0))
    assert len(tr) == len(va) == 0
