"""Zero-annotation training with self-training on a scene without a class: it trains to the
end, keeps the rough-only model of the class it could not self-train (so ``s2p run`` works),
says which class it skipped, and a re-run finds everything done instead of failing again."""

from __future__ import annotations

import numpy as np
from scene_fixtures import make_tiny_scene, s2p

from seg2pose.io.mots import read_mots, write_mots
from seg2pose.io.poses import read_poses, write_poses

TRAIN = ("--zero-annotation", "--self-train", "track", "--protocol", "demo", "--no-share-classes",
         "--epochs", "1", "--batches", "2", "--rough", "16", "--self-epochs", "1",
         "--camera", "c1", "--threads", "1")


def _scene_without_bicyclists(root):
    """The tiny scene's four road users (pedestrian, bicyclist, car, pedestrian) without the
    bicyclist (track 2), in masks and truth."""
    make_tiny_scene(root, frames=24, n_users=4, seed=2)
    for cam in ("c0", "c1", "c2"):
        path = root / "masks" / f"{cam}.txt"
        t = read_mots(path)
        write_mots(path, t.take(np.flatnonzero(t.track_id != 2)))
    gt = read_poses(root / "gt" / "poses.csv")
    write_poses(root / "gt" / "poses.csv", gt.take(np.flatnonzero(gt.track_id != 2)))


def test_no_bicyclists_trains_to_the_end_and_says_what_it_skipped(tmp_path, fake_rough,
                                                                   monkeypatch, capsys):
    from seg2pose.method.checkpoint import Checkpoint

    root = tmp_path / "scene"
    _scene_without_bicyclists(root)
    models = tmp_path / "models"
    code, out, err = s2p(monkeypatch, capsys, "train", root, "-o", models, *TRAIN)
    assert code == 0, err
    assert "skipped self-training of all__bicyclist: no bicyclist track" in err
    assert "skipped (rough-only model kept): all__bicyclist" in err
    assert "all__car" not in err.split("skipped (rough-only model kept):")[1]
    bic = Checkpoint.load(models / "all__bicyclist.safetensors")
    assert bic.info["complete"] and "no bicyclist track" in bic.info["self_training"]["skipped"]
    for cls in ("pedestrian", "car"):  # self-trained on their pseudo poses
        ck = Checkpoint.load(models / f"all__{cls}.safetensors")
        assert ck.info["complete"] and ck.info["self_training"]["n_pseudo"] > 0
    # the models run; a second call finds them done (it failed the same way before)
    code, out, err = s2p(monkeypatch, capsys, "run", root, "-c", "mono-1", "--models", models,
                         "-o", tmp_path / "run")
    assert code == 0, err
    code, out, err = s2p(monkeypatch, capsys, "train", root, "-o", models, *TRAIN)
    assert code == 0, err
    assert err.count("done already") >= 3 and "skipped self-training" not in err
