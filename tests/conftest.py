"""Fixtures shared by the whole suite. Helper modules (plain functions and constants) live beside
this file: scene_fixtures (the tiny 3-camera scene, the fast training protocol), review_fixtures,
video_fixtures, annotate_fixtures, hostile_fixtures, kill_harness with kill_cases and
command_zygote; pytest puts this folder on
``sys.path``, so tests in every sub-folder import them by name."""

from __future__ import annotations

import sys
import types

import pytest
from scene_fixtures import fake_rough_examples


@pytest.fixture()
def fake_rough(monkeypatch):
    """Rough-model examples from the box renderer instead of seg2pose.synth.rough (fast)."""
    mod = types.ModuleType("seg2pose.synth.rough")
    mod.render_rough_examples = fake_rough_examples
    monkeypatch.setitem(sys.modules, "seg2pose.synth.rough", mod)
