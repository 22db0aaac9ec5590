"""Synthetic traffic scenes (the CARLA stand-in) and rough 3D models (paper 3.5).

``generate_scene`` (a whole scene folder, ``SynthOptions``), ``NoiseConfig`` (the detector-noise knobs) and
``render_rough_examples`` are imported lazily, so that ``s2p --help`` stays fast.
"""

from __future__ import annotations

_LAZY = {
    "generate_scene": "seg2pose.synth.generate",
    "SynthOptions": "seg2pose.synth.generate",
    "PRESETS": "seg2pose.synth.generate",
    "NoiseConfig": "seg2pose.synth.noise",
    "render_rough_examples": "seg2pose.synth.rough",
    "make_device": "seg2pose.synth.rig",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seg2pose.synth' has no attribute {name!r}")
