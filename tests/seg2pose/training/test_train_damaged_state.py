"""A damaged resume state (issue 10): a truncated ``.state.pt`` is reported and set aside, and
training continues from the last good checkpoint instead of crashing with a torch traceback."""

from __future__ import annotations

import json

import pytest
from scene_fixtures import tiny_config, tiny_train_scene

tiny = pytest.fixture(scope="module")(tiny_train_scene)


def _interrupted(tiny, models, monkeypatch, after: int):
    """Train with 4 epochs, interrupted during the validation of epoch ``after + 1``."""
    import seg2pose.training.train as T

    calls = {"n": 0}
    real = T._evaluate

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == after + 1:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(T, "_evaluate", flaky)
    with pytest.raises(KeyboardInterrupt):
        T.train_scene(tiny, models, tiny_config(epochs=4, batches_per_epoch=2), cameras=["c0"],
                      progress=False)
    monkeypatch.setattr(T, "_evaluate", real)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_damaged_resume_state_restarts_from_the_last_good_checkpoint(tiny, tmp_path, fake_rough,
                                                                     monkeypatch, capsys, damage):
    import seg2pose.training.train as T

    models = tmp_path / "m"
    _interrupted(tiny, models, monkeypatch, after=2)
    path = models / "c0__all.safetensors"
    state = path.with_name(path.name + ".state.pt")
    best_epoch = json.loads(path.with_suffix(".json").read_text())["epoch"]
    raw = state.read_bytes()
    broken = raw[:len(raw) // 2] if damage == "truncate" else b"not a torch file"
    state.write_bytes(broken)
    capsys.readouterr()

    calls = {"n": 0}
    real = T._evaluate

    def counting(*a, **k):
        calls["n"] += 1
        return real(*a, **k)

    monkeypatch.setattr(T, "_evaluate", counting)
    T.train_scene(tiny, models, tiny_config(epochs=4, batches_per_epoch=2), cameras=["c0"],
                  progress=False)
    err = capsys.readouterr().err
    assert f"the resume state {state} is damaged" in err
    assert f"continuing from the last good checkpoint {path.name} (run 1, epoch {best_epoch})" in err
    damaged = sorted(models.glob("c0__all.safetensors.state.pt.damaged-*"))
    assert len(damaged) == 1 and damaged[0].read_bytes() == broken  # kept for a look
    assert not state.exists()  # the finished training removed its own (new) state
    assert calls["n"] == 4 - best_epoch  # the epochs after the last good checkpoint, no more
    assert json.loads(path.with_suffix(".json").read_text())["complete"] is True


def test_damaged_resume_state_without_a_checkpoint_starts_afresh(tiny, tmp_path, fake_rough,
                                                                 capsys):
    from seg2pose.training.train import train_scene

    models = tmp_path / "m"
    models.mkdir()
    state = models / "c0__all.safetensors.state.pt"
    state.write_bytes(b"\x80\x02garbage")
    train_scene(tiny, models, tiny_config(epochs=2, batches_per_epoch=2), cameras=["c0"],
                progress=False)
    err = capsys.readouterr().err
    assert "no checkpoint of this training to continue from, so it starts afresh" in err
    assert json.loads((models / "c0__all.json").read_text())["complete"] is True
    assert len(list(models.glob("*.damaged-*"))) == 1
