"""How the synthetic video looks beyond flat shading (issue 25's wider benchmark).

Two things a real junction's video has and the flat renderer had not, both hard on background
subtraction and on a network that learnt flat-shaded bodies:

- **a change of light**: clouds dim the sun for seconds at a time; the ground darkens, the
  shadows fade, the road users' sunlit faces lose their contrast, and the camera's
  auto-exposure makes up half of it (in log terms);
- **textured bodies**: striped or patterned clothes, two-tone paint, decals and dirt on vehicles.
  The pattern sticks to the road user (it moves and scales with it) and is the same in every
  camera, as a real road user's appearance is.

Only the video changes: masks and truth come from the geometry (``render.py``), so a scene's
``masks/`` and ``gt/`` are the same whatever its look.

Units: time in seconds, lengths on the body in metres, intensities in grey levels (0-255).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.core.errors import InputError

AMBIENT = 0.55   # share of a sunlit ground's light that is skylight (a shadow keeps 0.55 of it)
SUN_MIN = 0.2    # sun strength left under the thickest cloud
PLAIN, STRIPES, PATCHES = 0, 1, 2  # texture kinds


@dataclass(frozen=True)
class Look:
    """What the renderer adds to flat shading; recorded in scene.json extra.generator.look."""

    light_change: bool = False
    textures: bool = False


LOOKS = {"flat": Look(), "light": Look(light_change=True), "textured": Look(textures=True),
         "rich": Look(light_change=True, textures=True)}


def look_named(name: str) -> Look:
    if name not in LOOKS:
        raise InputError(f"unknown look {name!r}; use one of {', '.join(LOOKS)}", field="look")
    return LOOKS[name]


# --- light --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cloud:
    """One cloud passing the sun: a raised-cosine dip of ``depth`` centred at ``t0``."""

    t0: float    # s
    half: float  # s, half its duration
    depth: float  # 0 .. 1 - SUN_MIN: how much of the sun it takes at its thickest


def draw_clouds(seed: int, duration_s: float) -> list[Cloud]:
    """Clouds over ``duration_s`` seconds (deterministic per seed): one every 10-60 s, each
    4-12 s to either side of its centre, taking 30-80 % of the sun."""
    rng = np.random.default_rng([int(seed), 211])
    out: list[Cloud] = []
    t = float(rng.uniform(-10.0, 20.0))
    while t < duration_s + 12.0:
        half = float(rng.uniform(4.0, 12.0))
        out.append(Cloud(t, half, float(rng.uniform(0.3, 1.0 - SUN_MIN))))
        t += 2.0 * half + float(rng.exponential(25.0)) + 10.0
    return out


def sun_strength(clouds: list[Cloud], t: np.ndarray) -> np.ndarray:
    """(F,) share of the direct sunlight at times ``t`` (s): 1 in full sun, ``1 - depth`` at a
    cloud's centre, never below SUN_MIN."""
    t = np.asarray(t, float)
    s = np.ones_like(t)
    for c in clouds:
        x = np.clip((t - c.t0) / c.half, -1.0, 1.0)
        s *= 1.0 - c.depth * 0.5 * (1.0 + np.cos(np.pi * x))
    return np.maximum(s, SUN_MIN)


def ground_light(s: np.ndarray | float) -> np.ndarray | float:
    """Light on sunlit ground at sun strength ``s``, relative to full sun (1 at s = 1)."""
    return AMBIENT + (1.0 - AMBIENT) * s


def exposure_gain(s: np.ndarray | float) -> np.ndarray | float:
    """The camera's auto-exposure: it makes up half of the ground's change in log terms, so
    the video's background dims by sqrt(ground_light(s)) (1 at s = 1)."""
    return 1.0 / np.sqrt(ground_light(s))


# --- textures -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class BodyTextures:
    """Each road user's pattern, indexed by track id - 1 (so the same in every camera)."""

    kind: np.ndarray    # (T,) PLAIN / STRIPES / PATCHES
    amp: np.ndarray     # (T,) grey levels, the pattern's amplitude
    scale: np.ndarray   # (T,) metres: the stripes' period or the patches' size
    offset: np.ndarray  # (T, 2) metres: where the pattern starts on the body


# per class (index into shapes.CLASS_NAMES: pedestrian, bicyclist, car): shares of plain,
# striped and patterned bodies, and the range of the pattern's scale in metres
_KIND_SHARES = {0: (0.35, 0.35, 0.30), 1: (0.35, 0.35, 0.30), 2: (0.40, 0.15, 0.45)}
_SCALE_M = {STRIPES: (0.08, 0.35), PATCHES: (0.12, 0.6)}


def draw_textures(track_cls: np.ndarray, seed: int) -> BodyTextures:
    """A pattern per road user (``track_cls``: (T,) class index per track), deterministic per
    seed and the same in every camera."""
    rng = np.random.default_rng([int(seed), 212])
    T = len(track_cls)
    u = rng.random(T)
    shares = np.array([_KIND_SHARES[int(c)] for c in track_cls]).reshape(T, 3)
    kind = (u[:, None] >= np.cumsum(shares, axis=1)[:, :2]).sum(axis=1)
    lo = np.where(kind == STRIPES, _SCALE_M[STRIPES][0], _SCALE_M[PATCHES][0])
    hi = np.where(kind == STRIPES, _SCALE_M[STRIPES][1], _SCALE_M[PATCHES][1])
    scale = lo + (hi - lo) * rng.random(T)
    amp = np.where(kind == PLAIN, 0.0, rng.uniform(12.0, 40.0, T))
    return BodyTextures(kind.astype(np.int8), amp, scale, rng.uniform(0.0, 10.0, (T, 2)))


def _cell_noise(i: np.ndarray, j: np.ndarray, key: np.ndarray) -> np.ndarray:
    """A value in [-1, 1] per integer cell (i, j) and road user ``key`` (deterministic)."""
    a = np.sin(i * 12.9898 + j * 78.233 + key * 37.719) * 43758.5453
    return 2.0 * (a - np.floor(a)) - 1.0


def texture_values(tex: BodyTextures, track: np.ndarray, x: np.ndarray, y: np.ndarray
                   ) -> np.ndarray:
    """(N,) grey-level offsets of N body pixels: ``track`` (N,) their road users' ids (1-based),
    ``x``, ``y`` (N,) metres on the body (image right and down from the road user's centre,
    divided by its pixels per metre)."""
    k = track - 1
    x = x + tex.offset[k, 0]
    y = y + tex.offset[k, 1]
    sc = tex.scale[k]
    stripes = np.sin(2.0 * np.pi * y / sc)
    patches = _cell_noise(np.floor(x / sc), np.floor(y / sc), track.astype(float))
    v = np.where(tex.kind[k] == STRIPES, stripes, np.where(tex.kind[k] == PATCHES, patches, 0.0))
    return tex.amp[k] * v
