"""Fine-tuning from a start on a scene's annotations (``s2p train --from``,
seg2pose.training.fine_tune): which rows it uses, held-out road users never trained on, the
start counted as epoch 0, a class without annotations keeping its start, radial offsets kept
consistent, and start folders that do not fit refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene, s2p

from seg2pose.io.poses import PoseTable, read_poses, write_poses


def _annotate(root):
    """The tiny scene's truth as annotations: a keyframe every 5 frames, interpolated rows
    between; bicyclists (2, 5, 8) not annotated; pedestrian 7 only as unchecked estimates."""
    gt = read_poses(root / "gt" / "poses.csv")
    gt = gt.take(np.flatnonzero(~np.isin(gt.track_id, [2, 5, 8])))
    src = np.where(gt.frame % 5 == 0, "keyframe", "interpolated").astype(object)
    src[gt.track_id == 7] = "estimate-unchecked"
    write_poses(root / "gt" / "poses.csv", PoseTable(gt.frame, gt.track_id, gt.cls, gt.xyz,
                                                     gt.heading, gt.size, src))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("ft") / "scene"
    make_tiny_scene(root, frames=40, n_users=9, seed=3)
    _annotate(root)
    from seg2pose.io.scene import load_scene

    return load_scene(root)


def _opts(**kw):
    from seg2pose.training.fine_tune import FineTuneOptions

    # choose=False: the early-stopping path (the per-class choice: test_fine_tune_choice.py)
    base = dict(epochs=3, batches_per_epoch=4, batch_size=16, rough_per_class=16, lr=2e-3,
                threads=1, progress=False, choose=False)
    return FineTuneOptions(**{**base, **kw})


def _start(scene, folder):
    from seg2pose.training.fine_tune_data import scratch_start

    scratch_start(scene, folder, arch="lite", geometry=False)
    return folder


def _weights(path):
    from seg2pose.method.checkpoint import Checkpoint

    return Checkpoint.load(path).net.state_dict()


def test_usable_rows_skip_unchecked_occluded_and_the_test_split(scene):
    from seg2pose.training.fine_tune_data import usable_rows

    gt = read_poses(scene.gt_path)
    got = usable_rows(gt, scene)
    a, b = scene.split_range("test")  # frames 30-39
    assert not np.isin(got.track_id, [7]).any() and len(got)
    assert not ((got.frame >= a) & (got.frame <= b)).any()
    want = (gt.track_id != 7) & (gt.frame < a)
    assert len(got) == int(want.sum())
    assert set(got.source.tolist()) == {"keyframe", "interpolated"}


def test_fine_tuning_holds_out_road_users_and_keeps_unannotated_classes(scene, tmp_path, fake_rough):
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.training.fine_tune import fine_tune_scene

    start = _start(scene, tmp_path / "start")
    res = fine_tune_scene(scene, start, tmp_path / "out", _opts(min_held_out_users=2), cameras=["c1"])
    assert set(res.lines) == {"all__pedestrian.safetensors", "all__bicyclist.safetensors",
                              "all__car.safetensors"}
    assert "kept its start model (no annotated bicyclist masks)" in res.lines["all__bicyclist.safetensors"]
    for k, w in _weights(start / "all__bicyclist.safetensors").items():
        assert torch.equal(w, _weights(tmp_path / "out" / "all__bicyclist.safetensors")[k])
    for cls, users in (("pedestrian", {1, 4}), ("car", {3, 6, 9})):
        ck = Checkpoint.load(tmp_path / "out" / f"all__{cls}.safetensors")
        ft = ck.info["fine_tune"]
        tr, va = set(ft["road_users"]["train"]), set(ft["road_users"]["val"])
        assert tr | va == users and not tr & va and len(va) == 1  # round(0.2 n), at least one
        assert ft["val_error_m"] <= ft["start_val_error_m"]
        assert set(ft["examples_by_weight"]) == {"1.0", "4.0"}
        assert ck.info["complete"] and ck.scene_fingerprint == scene.fingerprint()
    # from scratch the held-out error comes down
    car = Checkpoint.load(tmp_path / "out" / "all__car.safetensors").info["fine_tune"]
    assert car["epoch"] > 0 and car["val_error_m"] < car["start_val_error_m"]


def test_with_few_road_users_nothing_is_held_out(scene, tmp_path, fake_rough):
    """By default a class holds out road users only from five annotated ones: the tiny scene's
    two pedestrians and three cars all train, the fixed schedule runs to its end."""
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.training.fine_tune import fine_tune_scene

    start = _start(scene, tmp_path / "start")
    res = fine_tune_scene(scene, start, tmp_path / "out", _opts(epochs=2), cameras=["c1"],
                          classes=["car"])
    assert res.lines["all__car.safetensors"] == "all__car: fine-tuned, epoch 2 of 2 run; nothing held out"
    ft = Checkpoint.load(tmp_path / "out" / "all__car.safetensors").info["fine_tune"]
    assert ft["road_users"] == {"train": [3, 6, 9], "val": []}


def test_the_start_is_epoch_zero(scene, tmp_path, fake_rough):
    """With a learning rate of 0 no epoch beats the start: its weights are kept, bit for bit."""
    from seg2pose.training.fine_tune import fine_tune_scene

    start = _start(scene, tmp_path / "start")
    res = fine_tune_scene(scene, start, tmp_path / "out", _opts(lr=0.0, epochs=2, min_held_out_users=2),
                          cameras=["c1"], classes=["car"])
    assert "no epoch beat the start model" in res.lines["all__car.safetensors"]
    for k, w in _weights(start / "all__car.safetensors").items():
        assert torch.equal(w, _weights(tmp_path / "out" / "all__car.safetensors")[k])


def test_radial_offset_of_the_start_is_added_to_the_targets(scene):
    """A start model that subtracts r along the camera-to-road-user direction (zero-annotation's
    radial calibration) trains on targets r further along it, so that it still predicts the
    truth: the difference is r times that unit vector."""
    from seg2pose.training.fine_tune_data import annotated_masks, usable_rows, weighted_examples

    gt = usable_rows(read_poses(scene.gt_path), scene)
    ann = annotated_masks(scene, "c1", gt.take(np.argsort(gt.frame, kind="stable")))
    plain = weighted_examples(scene, ann, 420, 3)
    shifted = weighted_examples(scene, ann, 420, 3, radial_offset={"car": 0.5, "pedestrian": -0.2})
    u = plain.ex.normal - scene.cameras["c1"].center[:2]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = np.where(plain.ex.cls == "car", 0.5, -0.2)
    np.testing.assert_allclose(shifted.ex.target - plain.ex.target, r[:, None] * u, atol=1e-12)
    assert set(plain.weight.tolist()) == {1.0, 4.0}


def _checkpoint(path, camera="*", cls="*", classes=("pedestrian", "bicyclist", "car"), size=(320, 240)):
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet

    net = Seg2PoseNet(NetConfig.named("lite", len(classes) if cls == "*" else 0))
    Checkpoint(net=net, norm=Normalisation(*size), camera=camera, cls=cls,
               classes=list(classes) if cls == "*" else [], info={"complete": True}).save(path)


@pytest.mark.parametrize("files, said", [
    ({"cam9__all.safetensors": dict(camera="cam9")},
     "holds models for cameras cam9; {root} has c0, c1, c2"),
    ({"all__all.safetensors": dict(classes=("person", "vehicle"))},
     "is for classes person, vehicle; {root} has pedestrian, bicyclist, car"),
    ({"all__truck.safetensors": dict(cls="truck")}, "has no model for class pedestrian"),
    ({"all__all.safetensors": dict(size=(640, 480))},
     "was made for 640x480 images; camera c0 of {root} has 320x240"),
])
def test_start_models_that_do_not_fit_are_refused_in_one_line(scene, tmp_path, monkeypatch, capsys,
                                                               files, said):
    folder = tmp_path / "other"
    folder.mkdir()
    for name, kw in files.items():
        _checkpoint(folder / name, **kw)
    code, out, err = s2p(monkeypatch, capsys, "train", scene.root, "--from", folder,
                         "-o", tmp_path / "out")
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert said.format(root=scene.root) in err
    assert not (tmp_path / "out").exists()


def test_the_shipped_folder_starts_from_its_first_member(scene):
    """``--from seg2pose/data/demo_models`` (the manifest's folder) means its first member; its
    models are for the device's images, not the tiny scene's 320x240."""
    from seg2pose.core.errors import S2PError
    from seg2pose.training.demo_models import SHIPPED
    from seg2pose.training.fine_tune_data import start_models

    with pytest.raises(S2PError, match=r"bench-seed7/all__car.safetensors was made for \d+x\d+ images; "
                                       r"camera c0 .* has 320x240"):
        start_models(scene, SHIPPED, ["c0"], ["car"])
