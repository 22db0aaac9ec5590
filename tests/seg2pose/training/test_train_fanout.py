"""The training fan-out (seg2pose/training/train_fanout.py) without Ray, through the plain ``map``:
the best of 2 runs picked as the serial protocol picks it (same bytes), and an interrupted
fan-out resumed without training its finished run again."""

from __future__ import annotations

import pytest

from seg2pose.training.train_fanout import run_path


def test_fan_out_resumes_and_matches_serial(tmp_path, monkeypatch):
    from scene_fixtures import make_tiny_scene, tiny_config

    import seg2pose.training.train as train
    from seg2pose.training.train import train_scene

    scene = make_tiny_scene(tmp_path / "tiny", frames=24, n_users=5, seed=2)
    cfg = tiny_config(rough_every=0, epochs=2, batches_per_epoch=3, runs=2, share_classes=False)
    kw = dict(cameras=["c0"], classes=["car"], progress=False)
    ser = train_scene(scene, tmp_path / "serial", cfg, **kw)

    calls = []
    real = train.train_model

    def counted(*a, **k):
        calls.append(k.get("runs") or a[-1])
        return real(*a, **k)

    monkeypatch.setattr(train, "train_model", counted)

    def interrupted(fn, items):  # the second run's task never finishes
        items = list(items)
        if len(items) == 2 and isinstance(items[0], tuple):
            fn(items[0])
            raise KeyboardInterrupt
        return [fn(x) for x in items]

    with pytest.raises(KeyboardInterrupt):
        train_scene(scene, tmp_path / "fan", cfg, map_groups=interrupted, **kw)
    assert (tmp_path / "fan" / "c0__car.run1.safetensors").exists()
    assert not (tmp_path / "fan" / "c0__car.safetensors").exists()
    assert run_path(tmp_path / "fan" / "c0__car.safetensors", 0).name == "c0__car.run1.safetensors"
    calls.clear()
    fan = train_scene(scene, tmp_path / "fan", cfg, map_groups=map, **kw)
    assert len(calls) == 1  # only run 2 trained; run 1's finished file was kept
    files = sorted(p.name for p in ser.iterdir())
    assert files == sorted(p.name for p in fan.iterdir()) == ["c0__car.json", "c0__car.safetensors"]
    for f in files:
        assert (ser / f).read_bytes() == (fan / f).read_bytes()
