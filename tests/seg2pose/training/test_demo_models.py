"""The Seg2PoseNet models shipped for ``s2p demo``: they load, fit the demo scene's device and
classes, are used without any training, and beat the baseline on a scene of the demo's seed;
``ship`` writes float16 copies that predict as the originals do; a misfit is one clear line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene

from seg2pose.core import say as say_mod
from seg2pose.method.checkpoint import Checkpoint, ModelSet, model_filename
from seg2pose.training import demo_models
from seg2pose.training.demo_models import SHIPPED


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The demo's junction and seed (small preset, seed 0), 30 frames per split, no video."""
    from seg2pose.io.scene import load_scene
    from seg2pose.method.heights import update_default_heights
    from seg2pose.synth import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("demo_small") / "scene"
    # one process: forked workers deadlock on locks that the suite's earlier threads (torch,
    # OpenCV) held at fork time (this fixture hung the whole suite in a fresh clone)
    generate_scene(root, SynthOptions(preset="small", seed=0, frames=30, progress=False, workers=1))
    scene = load_scene(root)
    update_default_heights(scene, split="train", log=lambda *_: None)
    return scene


def test_shipped_files_are_small_float16_and_say_where_they_come_from():
    m = demo_models.read_manifest()
    folders = demo_models.model_folders()
    assert [f.name for f in folders] == [f"bench-seed{s}" for s in demo_models.TRAIN_SEEDS]
    total = sum(f.stat().st_size for f in SHIPPED.rglob("*") if f.is_file())
    assert total < 3e6  # a few MB at most
    from safetensors import safe_open

    for folder in folders:
        files = sorted(folder.glob("*.safetensors"))
        assert [f.name for f in files] == sorted(model_filename("*", c) for c in m["classes"])
        for f in files:
            with safe_open(str(f), framework="pt") as h:
                assert {h.get_tensor(k).dtype for k in h.keys()} == {torch.float16}
                meta = json.loads(h.metadata()["s2p"])
            assert meta["cameras_fingerprint"] == m["cameras_fingerprint"]
            assert meta["complete"] is True and meta["arch"] == "lite-hr" and meta["net"]["n_geo"] > 0
    # trained on other scenes than the demo's (small preset, seed 0) with the quick protocol
    assert all(x["trained_on"]["seed"] != 0 and x["trained_on"]["preset"] == "bench"
               for x in m["members"]) and m["protocol"] == "quick"
    line = demo_models.describe(m)
    seeds = [x["trained_on"]["seed"] for x in m["members"]]
    assert f"seed{'s' if len(seeds) > 1 else ''} {' and '.join(map(str, seeds))} " in line
    assert "not this scene" in line and ("averaged" in line) == (len(seeds) > 1)


def test_shipped_models_fit_the_demo_scene_and_are_used_without_training(small, tmp_path,
                                                                         monkeypatch):
    from seg2pose.cli import demo
    from seg2pose.training import train

    assert demo_models.fit_problem(small) is None
    monkeypatch.setattr(train, "train_scene", lambda *a, **k: pytest.fail("the demo trained"))
    models, used = demo.choose_models(small, tmp_path / "m", retrain=False)
    assert models == demo_models.model_folders() and "shipped" in used and "seeds 7 and 8" in used
    assert not (tmp_path / "m").exists()


def test_shipped_models_beat_the_baseline_on_the_demo_seed(small, tmp_path):
    """A known answer the weights must earn: on the demo's junction and seed the shipped models
    cut the baseline's error (the full demo: about half; these 30 test frames: 0.59x)."""
    from seg2pose.eval.evaluate import evaluate, seen_truth
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_run_poses
    from seg2pose.method.pipeline import RunOptions, run_scene

    torch.set_num_threads(1)
    gt = read_poses(small.gt_path)
    test = small.split_range("test")
    seen = seen_truth(small, small.rig.configs["mono-1"], gt, test)
    err = {}
    for name, models in (("baseline", None), ("s2pn", demo_models.model_folders())):
        run = tmp_path / name
        run_scene(small, run, RunOptions(config="mono-1", baseline=models is None,
                                         models_dir=models, split="test", progress=False))
        err[name] = evaluate(read_run_poses(run), seen, small.rig.center[:2], frame_range=test)
    assert err["s2pn"].n_matched == err["baseline"].n_matched > 50
    assert err["s2pn"].mean_error < 0.7 * err["baseline"].mean_error


def test_a_scene_they_do_not_fit_gets_one_line_and_lite_training(tmp_path, monkeypatch, small):
    from seg2pose.cli import demo
    from seg2pose.training import train
    from seg2pose.training.config import TrainConfig

    tiny = make_tiny_scene(tmp_path / "tiny", frames=8, n_users=3)  # three other cameras
    problem = demo_models.fit_problem(tiny)
    assert "other cameras" in problem and "\n" not in problem
    calls = []
    monkeypatch.setattr(train, "train_scene", lambda scene, out, cfg, **k: calls.append((out, cfg, k)))
    models, used = demo.choose_models(tiny, tmp_path / "m", retrain=False)
    assert models == [tmp_path / "m"] and "this scene's train split" in used
    assert calls[0][1] == TrainConfig.demo() and calls[0][2]["settings"].force is False
    # --retrain trains afresh even where the shipped models fit
    demo.choose_models(small, tmp_path / "m2", retrain=True)
    assert calls[1][0] == tmp_path / "m2" and calls[1][2]["settings"].force is True

    # other classes; a folder without a manifest
    import dataclasses

    renamed = dataclasses.replace(small, classes=[dataclasses.replace(c, name=c.name + "x")
                                                  for c in small.classes])
    assert "classes" in demo_models.fit_problem(renamed)
    assert "no manifest" in demo_models.fit_problem(small, tmp_path)


def test_ship_writes_float16_copies_that_predict_like_the_originals(tmp_path, monkeypatch):
    """``ship`` on complete checkpoints of a tiny scene: float16 weights, the device mark, the
    manifest; predictions within float16's precision of the float32 model's; and ModelSet
    warns about them on other cameras only, not on another scene of the same cameras."""
    from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet

    scene = make_tiny_scene(tmp_path / "tiny", frames=8, n_users=3)
    src = tmp_path / "src"
    src.mkdir()
    torch.manual_seed(0)
    cam = scene.cameras["c0"]
    for cls in scene.class_names:
        ck = Checkpoint(net=Seg2PoseNet(NetConfig.lite()), norm=Normalisation.for_scene(
            scene.ground_points, cam.width, cam.height), camera="*", cls=cls,
            scene_fingerprint=scene.fingerprint(), info={"complete": True})
        ck.save(src / model_filename("*", cls))
    out = tmp_path / "shipped"
    written = demo_models.ship([(src, scene, {"train_s": 1.0})], out, {"command": "c"})
    assert out / demo_models.MANIFEST in written and out / "tiny" / "all__car.safetensors" in written
    m = demo_models.read_manifest(out)
    assert m["cameras_fingerprint"] == scene.cameras_fingerprint() and m["command"] == "c"
    assert m["members"] == [{"dir": "tiny", "trained_on": {
        "preset": None, "seed": None, "frames_per_split": None,
        "scene_fingerprint": scene.fingerprint()}, "default_heights": scene.default_heights(),
        "train_s": 1.0}]
    assert demo_models.model_folders(out) == [out / "tiny"]

    rng = np.random.default_rng(0)
    crops = (rng.random((6, 420, 420)) > 0.7).astype(np.uint8)
    centers = rng.uniform(100, 300, (6, 2))
    normal = rng.uniform(5, 20, (6, 2))
    a = Checkpoint.load(src / "all__car.safetensors").predict(crops, centers, normal)
    b = Checkpoint.load(out / "tiny" / "all__car.safetensors").predict(crops, centers, normal)
    assert np.abs(a - b).max() <= 2e-3 * max(np.abs(a).max(), 1.0)
    assert demo_models.fit_problem(scene, out) is None

    said = []
    monkeypatch.setattr(say_mod, "_sink", lambda msg, kind: said.append((kind, msg)))
    other_scene = scene.fingerprint() + "x"  # another scene of the same cameras: no warning
    ModelSet.load(out / "tiny", ["c0"], scene.class_names, fingerprint=other_scene,
                  cameras_fingerprint=scene.cameras_fingerprint())
    assert said == []
    ModelSet.load(out / "tiny", ["c0"], scene.class_names, fingerprint=other_scene,
                  cameras_fingerprint="0" * 16)
    assert said and all(k == "warning" and "other cameras" in msg for k, msg in said)
