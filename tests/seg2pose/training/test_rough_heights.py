"""Default heights from rough models (no annotations) against the bisection on ground truth."""

import pytest

from seg2pose.io.scene import load_scene
from seg2pose.method.heights import update_default_heights
from seg2pose.synth.generate import SynthOptions, generate_scene
from seg2pose.training.rough_heights import rough_height_views


def test_rough_heights_are_close_to_the_annotated_ones(tmp_path):
    generate_scene(tmp_path / "s", SynthOptions(frames=60, seed=5, progress=False, workers=1))
    scene = load_scene(tmp_path / "s")
    truth = update_default_heights(scene, "train", write=False, log=lambda s: None)
    scene = load_scene(tmp_path / "s")
    views = rough_height_views(scene, 600, seed=1, cameras=["c1"])
    rough = update_default_heights(scene, views=views, write=False, log=lambda s: None)
    for c in ("pedestrian", "car"):
        assert rough[c]["n"] == 600 and rough[c]["closer_share"] == pytest.approx(0.5, abs=0.01)
        # the rough models are cruder than the road users: within 12 cm of the annotated height
        assert rough[c]["new"] == pytest.approx(truth[c]["new"], abs=0.12), c
