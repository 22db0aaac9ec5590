"""The check on residuals the network never learned (seg2pose.method.ood): limits from training
residuals, flags, and a run that warns, lists and (with fallback) keeps normal positions."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scene_fixtures import tiny_config, tiny_train_scene

from seg2pose.method.ood import flag_far, flagged_poses, residual_limits

tiny = pytest.fixture(scope="module")(tiny_train_scene)


def test_limits_are_the_99th_percentile_of_training_residual_lengths():
    # lengths 0.00, 0.01, ..., 1.00 m in random directions: the 99th percentile is 0.99 m
    rng = np.random.default_rng(0)
    length = np.arange(101) / 100
    ang = rng.uniform(-np.pi, np.pi, 101)
    target = np.column_stack([length * np.cos(ang), length * np.sin(ang)])
    cls = np.array(["car"] * 101, object)
    lim = residual_limits(np.vstack([target, 2 * target]), np.concatenate([cls, ["pedestrian"] * 101]))
    assert lim == pytest.approx({"car": 0.99, "pedestrian": 1.98})


def test_flags_only_residuals_beyond_their_class_limit():
    res = np.array([[0.3, 0.4], [0.6, 0.8], [3.0, 0.0], [0.0, 0.5]])
    cls = np.array(["car", "car", "bus", "pedestrian"], object)
    flag, lim = flag_far(res, cls, {"car": 0.9, "pedestrian": 0.4})
    assert flag.tolist() == [False, True, False, True]   # 0.5 < 0.9 < 1.0; no limit for bus
    assert np.isnan(lim[2]) and lim[0] == 0.9
    assert not flag_far(res, cls, None)[0].any()         # an old checkpoint: nothing flagged
    assert flagged_poses(np.array([1, 1, 2, 5]), np.array([7, 7, 7, -1])) == 3


def test_a_run_lists_warns_and_falls_back_on_far_residuals(tiny, tmp_path, fake_rough):  # noqa: F811
    from typer.testing import CliRunner

    from seg2pose.cli import app
    from seg2pose.io.run import read_run_poses, read_views
    from seg2pose.method.checkpoint import Checkpoint
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.training.train import train_scene

    out = train_scene(tiny, tmp_path / "m", tiny_config(share_classes=False, epochs=1,
                                                        batches_per_epoch=2),
                      cameras=["c1"], progress=False)
    # training stored the limits: per class, the 99th percentile of what it trained on
    ck_path = out / "c1__pedestrian.safetensors"
    lim = Checkpoint.load(ck_path).info["residual_limit"]
    assert set(lim) == {"pedestrian"} and 0 < lim["pedestrian"] <= 2.5
    warn = run_scene(tiny, tmp_path / "warn", RunOptions(config="mono-1", models_dir=out, progress=False))
    meta = json.loads((warn / "run.json").read_text())["far_residuals"]
    v = read_views(warn / "views.csv")
    ped = v.cls == "pedestrian"
    n_far = int((np.linalg.norm(v.residual[ped], axis=1) > lim["pedestrian"]).sum())
    assert meta["flagged_views"] == n_far  # the known count: few, by construction of the limit
    # a known case: the pedestrian model told it never saw a residual longer than 1 mm
    ck = Checkpoint.load(ck_path)
    ck.info["residual_limit"] = {"pedestrian": 0.001}
    ck.save(ck_path)
    warn = run_scene(tiny, tmp_path / "warn2", RunOptions(config="mono-1", models_dir=out, progress=False,
                     force=True))
    v = read_views(warn / "views.csv")
    ped = v.cls == "pedestrian"
    far = ped & (np.linalg.norm(v.residual, axis=1) > 0.001)
    assert far.sum() >= 5
    meta = json.loads((warn / "run.json").read_text())["far_residuals"]
    assert meta == {"policy": "warn", "flagged_views": int(far.sum()),
                    "flagged_poses": int(far.sum()), "file": "flagged.csv"}
    rows = (warn / "flagged.csv").read_text().splitlines()
    assert rows[0] == "frame,track_id,camera,class,residual_m,limit_m" and len(rows) == far.sum() + 1
    assert {r.split(",")[3] for r in rows[1:]} == {"pedestrian"}
    listed = {(int(r.split(",")[0]), int(r.split(",")[1])) for r in rows[1:]}
    assert listed == set(zip(v.frame[far].tolist(), v.track_id[far].tolist()))
    # fallback: those poses stay at their normal positions, the others keep their residuals
    fb = run_scene(tiny, tmp_path / "fb", RunOptions(config="mono-1", models_dir=out, progress=False,
                   far_residuals="fallback"))
    vf = read_views(fb / "views.csv")
    np.testing.assert_array_equal(vf.residual[far], 0.0)
    np.testing.assert_allclose(vf.residual[~far], v.residual[~far])
    base = read_run_poses(run_scene(tiny, tmp_path / "base", RunOptions(config="mono-1", baseline=True,
                                    progress=False)))
    p = read_run_poses(fb)
    key = {(f, t): i for i, (f, t) in enumerate(zip(base.frame.tolist(), base.track_id.tolist()))}
    for f, t in listed:
        i = next(k for k, (ff, tt) in enumerate(zip(p.frame, p.track_id)) if (ff, tt) == (f, t))
        np.testing.assert_allclose(p.xyz[i, :2], base.xyz[key[(f, t)], :2], atol=1e-9)
    # the command line says how many and where
    r = CliRunner().invoke(app, ["run", str(tiny.root), "-o", str(tmp_path / "cli"), "-c", "mono-1",
                                 "--models", str(out)])
    assert r.exit_code == 0, r.output
    assert f"{int(far.sum())} poses ({int(far.sum())} views) were moved further" in r.output
    assert "flagged.csv" in r.output
    r = CliRunner().invoke(app, ["run", str(tiny.root), "-o", str(tmp_path / "off"), "-c", "mono-1",
                                 "--models", str(out), "--far-residuals", "off"])
    assert r.exit_code == 0 and "moved further" not in r.output
    assert not (tmp_path / "off" / "flagged.csv").exists()
