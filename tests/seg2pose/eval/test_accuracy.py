"""The accuracy benchmark's bookkeeping (seg2pose/eval/accuracy.py): ratios from paper-table
results, mean and spread over seeds, resumption without re-running finished steps."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seg2pose.cli import accuracy
from seg2pose.core.errors import S2PError
from seg2pose.eval.accuracy import SeedResult, class_ratios, ratios, read_table, summary


def write_table(path, errors: dict, s2pn: dict, per_class: dict | None = None):
    """A results.json as paper-table writes it: '<config> baseline' / '<config> S2PN'."""
    path.mkdir(parents=True, exist_ok=True)
    res = {}
    for cfg, e in errors.items():
        res[f"{cfg} baseline"] = {"mean_error": e, "per_class": (per_class or {}).get("b", {})}
        res[f"{cfg} S2PN"] = {"mean_error": s2pn[cfg], "per_class": (per_class or {}).get("s", {})}
    (path / "results.json").write_text(json.dumps({"results": res}))


def test_ratios_mean_and_spread(tmp_path):
    results = []
    for seed, (b, s) in enumerate([(0.30, 0.12), (0.20, 0.10), (0.25, 0.075)]):
        r = SeedResult(seed)
        write_table(tmp_path / str(seed), {"mono-1": b, "tri-I": b}, {"mono-1": s, "tri-I": s / 2},
                    {"b": {"car": 0.4}, "s": {"car": 0.1 * (seed + 1)}})
        read_table(tmp_path / str(seed) / "results.json", "s2pn", r)
        results.append(r)
    np.testing.assert_allclose(ratios(results, "s2pn", "mono-1"), [0.4, 0.5, 0.3])
    np.testing.assert_allclose(ratios(results, "s2pn", "tri-I"), [0.2, 0.25, 0.15])
    np.testing.assert_allclose(class_ratios(results, "s2pn", "mono-1", "car"), [0.25, 0.5, 0.75])
    text = summary(results, ("s2pn",))
    assert "mono-1" in text and "0.400x (0.30-0.50)" in text and "0.200x (0.15-0.25)" in text
    assert "mono-1 car" in text and "0.500x (0.25-0.75)" in text


def test_bad_results_file_names_it(tmp_path):
    p = tmp_path / "results.json"
    p.write_text("{}")
    with pytest.raises(S2PError, match="results.json"):
        read_table(p, "s2pn", SeedResult(0))


def test_finished_steps_are_skipped(tmp_path, monkeypatch):
    """With the scene, the models' bench.json and the table present, nothing is run again."""
    scene = tmp_path / "bench-seed7"
    scene.mkdir()
    (scene / "scene.json").write_text("{}")
    (scene / "models-s2pn").mkdir()
    (scene / "models-s2pn" / "bench.json").write_text(json.dumps({"train_s": 600.0}))
    write_table(scene / "table-s2pn", {"mono-1": 0.3}, {"mono-1": 0.15})
    monkeypatch.setattr(accuracy.subprocess, "run", lambda *a, **k: pytest.fail("ran a step"))
    r = accuracy.run_seed(tmp_path, 7, variants=("s2pn",), log=lambda s: None)
    assert r.train_s == {"s2pn": 600.0} and r.errors["mono-1"] == {"baseline": 0.3, "s2pn": 0.15}


def test_steps_are_the_user_commands(tmp_path, monkeypatch):
    """A fresh seed runs synth, heights, train and paper-table as `s2p` commands, in order."""
    ran = []

    def fake_run(argv, **kw):
        args = argv[3:]
        ran.append(args[0])
        if args[0] == "synth":
            (tmp_path / "bench-seed3").mkdir()
            (tmp_path / "bench-seed3" / "scene.json").write_text("{}")
        if args[0] == "train":
            (tmp_path / "bench-seed3" / "models-zero").mkdir()
            assert args[-4:] == ["--threads", "1", "-o", str(tmp_path / "bench-seed3" / "models-zero")]
            assert "--zero-annotation" in args and "--epochs=3" in args
        if args[0] == "paper-table":
            write_table(tmp_path / "bench-seed3" / "table-zero", {"tri-I": 0.2}, {"tri-I": 0.1})
        return accuracy.subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(accuracy.subprocess, "run", fake_run)
    log = []
    r = accuracy.run_seed(tmp_path, 3, variants=("zero",), threads=1, train_args=("--epochs=3",),
                          log=log.append)
    assert ran == ["synth", "heights", "train", "paper-table"]
    assert log[0].startswith("$ s2p synth ") and "--seed 3" in log[0]
    assert (tmp_path / "logs" / "seed3-train-zero.log").exists()
    assert r.errors["tri-I"] == {"baseline": 0.2, "zero": 0.1}


def test_self_training_variant_starts_from_the_finished_zero_models(tmp_path, monkeypatch):
    """zero-views after a finished zero: zero's models are copied in as the rough-only stage
    (not retrained: training then skips them), without zero's bench.json."""
    scene = tmp_path / "bench-seed5"
    (scene / "models-zero").mkdir(parents=True)
    (scene / "scene.json").write_text("{}")
    (scene / "models-zero" / "bench.json").write_text(json.dumps({"train_s": 60.0}))
    (scene / "models-zero" / "all__car.json").write_text("{}")
    write_table(scene / "table-zero", {"tri-I": 0.2}, {"tri-I": 0.1})
    trained = []

    def fake_run(argv, **kw):
        args = argv[3:]
        if args[0] == "train":
            trained.append(args)
            assert (scene / "models-zero-views" / "rough-stage" / "all__car.json").exists()
            assert not (scene / "models-zero-views" / "rough-stage" / "bench.json").exists()
            assert args[args.index("--self-train") + 1] == "views"
        if args[0] == "paper-table":
            write_table(scene / "table-zero-views", {"tri-I": 0.2}, {"tri-I": 0.08})
        return accuracy.subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(accuracy.subprocess, "run", fake_run)
    r = accuracy.run_seed(tmp_path, 5, variants=("zero", "zero-views"), log=lambda s: None)
    assert len(trained) == 1 and r.errors["tri-I"] == {"baseline": 0.2, "zero": 0.1, "zero-views": 0.08}
    assert "0.400x" in summary([r], ("zero", "zero-views"))  # every variant has a title
