"""The wide preset (issue 25): road users of many kinds and sizes, the pole 6-15 m high."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.synth.generate import check_sees_road
from seg2pose.synth.rig import device_at
from seg2pose.synth.shapes_wide import KIND_SHARES, WIDE_MAKERS


def sizes(cls: str, n: int = 300, kind: str | None = None) -> np.ndarray:
    rng = np.random.default_rng(5)
    return np.array([WIDE_MAKERS[cls](rng, kind).size for _ in range(n)])


def test_kinds_span_small_cars_to_buses_children_to_tall_adults():
    car = sizes("car")
    assert car[:, 0].min() < 3.7 and car[:, 0].max() > 10.0 and car[:, 2].max() > 2.9
    ped_h = sizes("pedestrian")[:, 2]
    assert ped_h.min() < 1.3 and ped_h.max() > 1.9
    bike = sizes("bicyclist")
    assert bike[:, 0].max() > 2.2 and bike[:, 2].min() < 1.45
    for cls, kinds in KIND_SHARES.items():  # every kind builds, within plausible sizes
        for k in kinds:
            s = sizes(cls, 5, k)
            assert (s > 0.1).all() and (s[:, 0] < 12.5).all() and (s[:, 2] < 4.0).all(), (cls, k)


def test_device_heights():
    for h in (6.0, 15.0):
        rig = device_at(h)
        assert rig.name == f"device-{h:g}m"
        assert rig.cameras["c1"].center[2] == pytest.approx(h)
        check_sees_road(rig)
    with pytest.raises(InputError, match="within 6-15 m"):
        device_at(20.0)


def test_wide_scene(tmp_path):
    from seg2pose.synth.generate import SynthOptions, generate_scene

    out = generate_scene(tmp_path / "w", SynthOptions(
        preset="wide", frames=4, seed=3, progress=False,
        population={"car": 4, "pedestrian": 4, "bicyclist": 2}, workers=1))
    g = json.loads((out / "scene.json").read_text())["extra"]["generator"]
    assert g["variety"] == "wide" and g["preset"] == "wide"
    h = float(g["rig"].removeprefix("device-").removesuffix("m"))
    assert 6.0 <= h <= 15.0
    # the rough models (the user's prior) stay the classes' typical sizes
    assert json.loads((out / "scene.json").read_text())["extra"]["class_sizes"]["car"] == [4.4, 1.82, 1.5]
