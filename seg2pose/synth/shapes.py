"""Road-user shapes as unions of convex hexahedra ("parts"), in a local frame.

Local frame: metres, x forward, y left, z up, origin at the bottom centre (the ground contact
point of the ground truth). A part is 8 vertices (8, 3): the bottom face's four corners
(-x,-y), (+x,-y), (+x,+y), (-x,+y), then the top face's in the same order, so boxes and
frustums (a cabin with a sloped windscreen, a torso wider at the shoulders) share one layout.

The benchmark's road users (``car_parts`` etc.) are deliberately more detailed than the rough
training models of ``rough.py`` (paper 3.5): a car is body + cabin + wheels, a pedestrian legs +
torso + arms + head, a bicyclist bike + rider.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# face vertex indices of a part (outward order is not needed: faces are filled as polygons)
FACES = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6],
                  [3, 0, 4, 7]])

# part kinds (for colours in the video)
BODY, GLASS, WHEEL, SKIN, TOP, LEGS, FRAME = range(7)

CLASS_NAMES = ("pedestrian", "bicyclist", "car")
TYPICAL_SIZES = {  # l, w, h metres (scene.json extra.class_sizes)
    "pedestrian": [0.3, 0.5, 1.72],
    "bicyclist": [1.75, 0.6, 1.75],
    "car": [4.4, 1.82, 1.5],
}


def hexa(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float,
         top: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """A box, or a frustum when ``top`` = (x0, x1, y0, y1) of the top face: (8, 3) metres."""
    tx0, tx1, ty0, ty1 = top if top is not None else (x0, x1, y0, y1)
    return np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                     [tx0, ty0, z1], [tx1, ty0, z1], [tx1, ty1, z1], [tx0, ty1, z1]], float)


@dataclass
class Shape:
    """One road user's parts: verts (P, 8, 3) local metres, kind (P,) part kinds, swing (P,)
    metres of fore-aft swing per unit sin(gait phase) (legs and arms), size (3,) l, w, h."""

    verts: np.ndarray
    kind: np.ndarray
    swing: np.ndarray
    size: np.ndarray


def make_shape(parts: list[tuple[np.ndarray, int, float]]) -> Shape:
    verts = np.stack([p[0] for p in parts])
    kind = np.array([p[1] for p in parts], np.int8)
    swing = np.array([p[2] for p in parts], float)
    lo, hi = verts.reshape(-1, 3).min(0), verts.reshape(-1, 3).max(0)
    size = np.array([hi[0] - lo[0], hi[1] - lo[1], hi[2]])
    return Shape(verts, kind, swing, size)


def car_parts(rng: np.random.Generator) -> Shape:
    """A car: body, a cabin with sloped windscreen and rear window, four wheels."""
    van = rng.random() < 0.12
    l = rng.uniform(5.0, 5.5) if van else rng.uniform(3.8, 5.0)
    w = rng.uniform(1.85, 2.05) if van else rng.uniform(1.7, 1.95)
    h = rng.uniform(1.9, 2.1) if van else rng.uniform(1.35, 1.6)
    r = rng.uniform(0.3, 0.35)
    hb = h * (0.62 if van else rng.uniform(0.5, 0.56))  # top of the body (bonnet line)
    parts = [(hexa(-l / 2, l / 2, -w / 2, w / 2, 0.28, hb), BODY, 0.0)]
    c0 = -l / 2 + (0.1 * l if van else rng.uniform(0.15, 0.3) * l)  # rear of the cabin
    c1 = l / 2 - (0.2 * l if van else rng.uniform(0.3, 0.38) * l)   # front of the cabin
    slope_f = (0.1 if van else rng.uniform(0.18, 0.26)) * l
    slope_r = (0.02 if van else rng.uniform(0.05, 0.15)) * l
    parts.append((hexa(c0, c1, -0.47 * w, 0.47 * w, hb, h,
                       top=(c0 + slope_r, c1 - slope_f, -0.4 * w, 0.4 * w)), GLASS, 0.0))
    ax = l / 2 - rng.uniform(0.7, 0.9)
    for sx in (-1, 1):
        for sy in (-1, 1):
            x = sx * ax
            y = sy * (w / 2 - 0.13)
            parts.append((hexa(x - r, x + r, y - 0.11, y + 0.11, 0.0, 2 * r), WHEEL, 0.0))
    return make_shape(parts)


def pedestrian_parts(rng: np.random.Generator) -> Shape:
    """A pedestrian: two legs and two arms that swing with the gait, a torso wider at the
    shoulders, a head."""
    h = float(np.clip(rng.normal(1.72, 0.09), 1.45, 1.98))
    w = rng.uniform(0.42, 0.54)   # shoulders
    d = rng.uniform(0.22, 0.3)    # torso depth
    hip, sh = 0.48 * h, 0.82 * h
    parts = []
    for sy, sgn in ((-1, 1.0), (1, -1.0)):
        y = sy * 0.09
        parts.append((hexa(-0.07, 0.07, y - 0.065, y + 0.065, 0.0, hip + 0.02), LEGS, 0.16 * sgn))
        ya = sy * (w / 2 - 0.045)
        parts.append((hexa(-0.045, 0.045, ya - 0.045, ya + 0.045, 0.5 * h, sh - 0.01), TOP,
                      -0.09 * sgn))
    parts.append((hexa(-d / 2, d / 2, -0.17, 0.17, hip, sh,
                       top=(-d / 2, d / 2, -(w / 2 - 0.09), w / 2 - 0.09)), TOP, 0.0))
    parts.append((hexa(-0.1, 0.1, -0.085, 0.085, sh, h), SKIN, 0.0))
    return make_shape(parts)


def bicyclist_parts(rng: np.random.Generator) -> Shape:
    """A bicyclist: two wheels, frame, handlebar, and a rider (legs, leaning torso, head)."""
    l = rng.uniform(1.65, 1.85)
    rw = rng.uniform(0.32, 0.36)  # wheel radius
    h = float(np.clip(rng.normal(1.75, 0.07), 1.55, 1.95))
    w = rng.uniform(0.55, 0.65)  # handlebar
    parts = []
    for sx in (-1, 1):
        x = sx * (l / 2 - rw)
        parts.append((hexa(x - rw, x + rw, -0.025, 0.025, 0.0, 2 * rw), WHEEL, 0.0))
    fx0, fx1 = -l / 2 + rw, l / 2 - rw
    parts.append((hexa(fx0, fx1, -0.03, 0.03, rw, rw + 0.5, top=(fx0 + 0.15, fx1 - 0.05, -0.03, 0.03)),
                  FRAME, 0.0))
    parts.append((hexa(fx1 - 0.12, fx1 - 0.02, -w / 2, w / 2, 1.0, 1.08), FRAME, 0.0))
    seat = rw + 0.6
    parts.append((hexa(-0.2, 0.15, -0.17, 0.17, rw - 0.05, seat), LEGS, 0.0))
    hs = h - 0.25  # shoulders
    lean = rng.uniform(0.2, 0.4)
    parts.append((hexa(-0.3, -0.02, -0.18, 0.18, seat, hs,
                       top=(-0.3 + lean, -0.02 + lean, -0.2, 0.2)), TOP, 0.0))
    parts.append((hexa(-0.12 + lean, 0.08 + lean, -0.09, 0.09, hs, h), SKIN, 0.0))
    return make_shape(parts)


MAKERS = {"pedestrian": pedestrian_parts, "bicyclist": bicyclist_parts, "car": car_parts}
