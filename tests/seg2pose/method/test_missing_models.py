"""`s2p run --models M --missing baseline`: cameras and classes without a model run the baseline
(normal positions), and the run says so (run.json, the output); refused without it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scene_fixtures import make_tiny_scene, s2p

from seg2pose.core.errors import S2PError
from seg2pose.method.checkpoint import Checkpoint, model_filename
from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet


def _car_model(scene, folder):
    """An untrained (random, non-zero output) model for cars only, on every camera."""
    folder.mkdir()
    torch.manual_seed(0)
    cam = scene.cameras["c0"]
    ck = Checkpoint(net=Seg2PoseNet(NetConfig.lite()), norm=Normalisation.for_scene(
        scene.ground_points, cam.width, cam.height), camera="*", cls="car",
        scene_fingerprint=scene.fingerprint(), info={"complete": True})
    ck.save(folder / model_filename("*", "car"))
    return folder


def test_classes_without_a_model_fall_back_to_the_baseline(tmp_path, monkeypatch, capsys):
    from seg2pose.io.run import read_run_meta, read_views
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = make_tiny_scene(tmp_path / "tiny", frames=6, n_users=6)
    models = _car_model(scene, tmp_path / "m")
    others = sorted(set(scene.class_names) - {"car"})
    with pytest.raises(S2PError, match="no Seg2PoseNet model in .* for c0/pedestrian, c0/bicyclist, c1/"):
        run_scene(scene, tmp_path / "r0", RunOptions(models_dir=models, progress=False))
    run = run_scene(scene, tmp_path / "r1", RunOptions(models_dir=models, progress=False,
                                                       missing="baseline"))
    meta = read_run_meta(run)
    cams = list(scene.cameras)
    assert meta["method"] == "seg2posenet" and sorted(meta["models"]) == [f"{c}/car" for c in cams]
    assert sorted(meta["baseline_fallback"]) == sorted(f"{c}/{k}" for c in cams for k in others)
    v = read_views(run / "views.csv")
    car = v.cls == "car"
    assert car.any() and (~car).any()
    assert np.all(v.residual[~car] == 0.0)          # the baseline: the normal position
    assert np.abs(v.residual[car]).max() > 0.0      # the model moved the cars
    code, out, err = s2p(monkeypatch, capsys, "run", scene.root, "-o", tmp_path / "r2", "--models",
                         models, "--missing", "baseline")
    assert code == 0, err
    assert f"no model for {cams[0]}/pedestrian" in err and "--missing baseline" in err
    assert json.loads((tmp_path / "r2" / "run.json").read_text())["baseline_fallback"]
