"""The ``wide`` preset's road users: more kinds and sizes than the benchmark's (``shapes.py``),
so that the world is no longer close to the rough training models (which stay as they are:
they are the user's prior, not the world).

Each maker draws a *kind* and builds it from the same hexahedron parts (local frame of
``shapes.py``: metres, x forward, y left, z up, origin at the bottom centre). Kinds are mapped
to the scene's three classes as a detector's would be:

- car: small car, car, SUV, van, truck, bus (COCO car / truck / bus -> car);
- bicyclist: bicycles under riders of several builds, cargo bikes, children on bikes, and
  motorcycles (a rider on two wheels; COCO motorcycle -> bicyclist);
- pedestrian: children to tall adults, some with a bag or backpack, some pushing a stroller.

``KIND_SHARES`` gives each kind's probability; ``kind_of`` names the kind a shape was drawn
as (for the scene's statistics).
"""

from __future__ import annotations

import numpy as np

from seg2pose.synth.shapes import BODY, FRAME, GLASS, LEGS, SKIN, TOP, WHEEL, Shape, hexa, make_shape

KIND_SHARES = {
    "car": {"small car": 0.2, "car": 0.34, "suv": 0.2, "van": 0.12, "truck": 0.08, "bus": 0.06},
    "bicyclist": {"bicycle": 0.6, "cargo bike": 0.08, "child bicycle": 0.1, "motorcycle": 0.22},
    "pedestrian": {"adult": 0.55, "adult with bag": 0.25, "child": 0.12, "stroller": 0.08},
}
# vehicles: length, width, height ranges (metres), share of the height that is body (the
# rest glass / cabin), whether the cabin spans the whole length (vans, buses)
VEHICLES = {
    "small car": ((3.4, 4.0), (1.6, 1.75), (1.4, 1.55), 0.52, False),
    "car": ((4.0, 4.9), (1.72, 1.88), (1.38, 1.52), 0.52, False),
    "suv": ((4.4, 5.0), (1.85, 2.0), (1.65, 1.85), 0.58, False),
    "van": ((5.0, 6.2), (1.95, 2.1), (2.1, 2.6), 0.6, True),
    "truck": ((7.0, 10.0), (2.4, 2.55), (3.0, 3.7), 0.85, False),
    "bus": ((10.5, 12.0), (2.5, 2.55), (2.95, 3.2), 0.45, True),
}


def _pick(rng: np.random.Generator, shares: dict[str, float]) -> str:
    names = list(shares)
    p = np.array([shares[k] for k in names])
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def vehicle_parts(rng: np.random.Generator, kind: str | None = None) -> Shape:
    """A vehicle of ``kind`` (drawn from KIND_SHARES["car"] when None)."""
    kind = kind or _pick(rng, KIND_SHARES["car"])
    (l0, l1), (w0, w1), (h0, h1), body_share, boxy = VEHICLES[kind]
    l, w, h = rng.uniform(l0, l1), rng.uniform(w0, w1), rng.uniform(h0, h1)
    r = 0.5 if kind in ("truck", "bus") else rng.uniform(0.3, 0.37)
    hb = h * body_share
    parts = [(hexa(-l / 2, l / 2, -w / 2, w / 2, 0.25 + 0.1 * (r > 0.4), hb), BODY, 0.0)]
    if kind == "truck":  # a cab in front of a tall box: the box is the body, the cab glass
        cab = rng.uniform(1.8, 2.3)
        parts = [(hexa(-l / 2, l / 2 - cab - 0.2, -w / 2, w / 2, 0.9, h), BODY, 0.0),
                 (hexa(l / 2 - cab, l / 2, -w / 2, w / 2, 0.6, 0.55 * h), BODY, 0.0),
                 (hexa(l / 2 - cab, l / 2, -0.48 * w, 0.48 * w, 0.55 * h, 0.8 * h,
                       top=(l / 2 - cab, l / 2 - 0.3, -0.45 * w, 0.45 * w)), GLASS, 0.0)]
    elif boxy:
        parts.append((hexa(-l / 2 + 0.1, l / 2 - 0.15, -0.48 * w, 0.48 * w, hb, h,
                           top=(-l / 2 + 0.1, l / 2 - 0.4, -0.46 * w, 0.46 * w)), GLASS, 0.0))
    else:
        c0 = -l / 2 + rng.uniform(0.12, 0.28) * l
        c1 = l / 2 - rng.uniform(0.28, 0.36) * l
        parts.append((hexa(c0, c1, -0.47 * w, 0.47 * w, hb, h,
                           top=(c0 + rng.uniform(0.04, 0.12) * l, c1 - rng.uniform(0.15, 0.24) * l,
                                -0.4 * w, 0.4 * w)), GLASS, 0.0))
    axles = [l / 2 - max(0.8, 0.12 * l), -(l / 2 - max(0.8, 0.15 * l))]
    if l > 9.0:
        axles.append(axles[1] + 1.4)
    for x in axles:
        for sy in (-1, 1):
            y = sy * (w / 2 - 0.15)
            parts.append((hexa(x - r, x + r, y - 0.13, y + 0.13, 0.0, 2 * r), WHEEL, 0.0))
    return make_shape(parts)


def person_parts(h: float, w: float, d: float, bag: str | None = None) -> list:
    """A walking person of height ``h``, shoulder width ``w``, torso depth ``d`` (metres),
    with an optional bag: "side" (a shoulder bag) or "back" (a backpack)."""
    hip, sh = 0.48 * h, 0.82 * h
    parts = []
    for sy, sgn in ((-1, 1.0), (1, -1.0)):
        y = sy * 0.052 * h
        parts.append((hexa(-0.04 * h, 0.04 * h, y - 0.038 * h, y + 0.038 * h, 0.0, hip + 0.02),
                      LEGS, 0.09 * h * sgn))
        ya = sy * (w / 2 - 0.045)
        parts.append((hexa(-0.045, 0.045, ya - 0.045, ya + 0.045, 0.5 * h, sh - 0.01), TOP,
                      -0.05 * h * sgn))
    parts.append((hexa(-d / 2, d / 2, -0.1 * h, 0.1 * h, hip, sh,
                       top=(-d / 2, d / 2, -(w / 2 - 0.09), w / 2 - 0.09)), TOP, 0.0))
    hr = 0.06 * h + 0.015  # children have relatively larger heads
    parts.append((hexa(-hr, hr, -0.85 * hr, 0.85 * hr, sh, h), SKIN, 0.0))
    if bag == "side":
        parts.append((hexa(-0.15, 0.15, w / 2, w / 2 + 0.12, 0.42 * h, 0.62 * h), BODY, 0.0))
    elif bag == "back":
        parts.append((hexa(-d / 2 - 0.2, -d / 2, -0.16, 0.16, 0.55 * h, 0.8 * h), BODY, 0.0))
    return parts


def pedestrian_parts(rng: np.random.Generator, kind: str | None = None) -> Shape:
    """A pedestrian of ``kind`` (drawn from KIND_SHARES["pedestrian"] when None)."""
    kind = kind or _pick(rng, KIND_SHARES["pedestrian"])
    if kind == "child":
        h = rng.uniform(0.95, 1.45)
        parts = person_parts(h, 0.27 * h, 0.15 * h)
        return make_shape(parts)
    h = float(np.clip(rng.normal(1.72, 0.1), 1.45, 2.02))
    w, d = rng.uniform(0.4, 0.56), rng.uniform(0.22, 0.32)
    bag = rng.choice(["side", "back"]) if kind == "adult with bag" else None
    parts = person_parts(h, w, d, bag)
    if kind == "stroller":  # pushed in front: a basket on a frame, four small wheels
        x0, x1 = 0.35, 0.35 + rng.uniform(0.75, 0.9)
        parts.append((hexa(x0 + 0.1, x1, -0.27, 0.27, 0.35, rng.uniform(0.85, 1.05)), BODY, 0.0))
        parts.append((hexa(x0, x0 + 0.1, -0.25, 0.25, 0.2, 1.0), FRAME, 0.0))
        for x in (x0 + 0.15, x1 - 0.1):
            for sy in (-1, 1):
                parts.append((hexa(x - 0.09, x + 0.09, sy * 0.26 - 0.03, sy * 0.26 + 0.03,
                                   0.0, 0.18), WHEEL, 0.0))
    return make_shape(parts)


def bicyclist_parts(rng: np.random.Generator, kind: str | None = None) -> Shape:
    """A rider on two wheels of ``kind`` (drawn from KIND_SHARES["bicyclist"] when None)."""
    kind = kind or _pick(rng, KIND_SHARES["bicyclist"])
    moto = kind == "motorcycle"
    if kind == "child bicycle":
        l, rw, h = rng.uniform(1.2, 1.4), rng.uniform(0.22, 0.27), rng.uniform(1.15, 1.4)
    elif kind == "cargo bike":
        l, rw, h = rng.uniform(2.3, 2.6), rng.uniform(0.3, 0.34), float(np.clip(rng.normal(1.75, 0.08), 1.5, 2.0))
    elif moto:
        l, rw, h = rng.uniform(1.9, 2.3), rng.uniform(0.3, 0.34), rng.uniform(1.35, 1.55)
    else:
        l, rw, h = rng.uniform(1.6, 1.9), rng.uniform(0.31, 0.36), float(np.clip(rng.normal(1.75, 0.09), 1.5, 2.02))
    bar = rng.uniform(0.55, 0.65) if not moto else rng.uniform(0.75, 0.85)
    parts = []
    for sx in (-1, 1):
        x = sx * (l / 2 - rw)
        tw = 0.07 if moto else 0.025
        parts.append((hexa(x - rw, x + rw, -tw, tw, 0.0, 2 * rw), WHEEL, 0.0))
    fx0, fx1 = -l / 2 + rw, l / 2 - rw
    if moto:  # engine and tank: a solid body between the wheels
        parts.append((hexa(fx0 - 0.1, fx1, -0.2, 0.2, 0.25, 0.85, top=(fx0, fx1 - 0.15, -0.15, 0.15)),
                      BODY, 0.0))
    else:
        parts.append((hexa(fx0, fx1, -0.03, 0.03, rw, rw + 0.45 * h / 1.75,
                           top=(fx0 + 0.15, fx1 - 0.05, -0.03, 0.03)), FRAME, 0.0))
    if kind == "cargo bike":  # a box in front of the rider
        parts.append((hexa(fx1 - 0.9, fx1 + 0.05, -0.32, 0.32, 0.25, 0.85), BODY, 0.0))
    seat = (0.85 if moto else rw + 0.6 * h / 1.75)
    parts.append((hexa(fx1 - 0.12, fx1 - 0.02, -bar / 2, bar / 2, seat + 0.2, seat + 0.28), FRAME, 0.0))
    parts.append((hexa(-0.2, 0.15, -0.17, 0.17, max(rw - 0.05, 0.2), seat), LEGS, 0.0))
    hs = h - 0.25 * h / 1.75  # shoulders
    lean = rng.uniform(0.2, 0.4)
    sw = 0.2 * h / 1.75
    parts.append((hexa(-0.3, -0.02, -0.9 * sw, 0.9 * sw, seat, hs,
                       top=(-0.3 + lean, -0.02 + lean, -sw, sw)), TOP, 0.0))
    head = 0.13 if moto else 0.1  # a helmet
    parts.append((hexa(-head + lean, head + lean, -0.9 * head, 0.9 * head, hs, h), SKIN, 0.0))
    return make_shape(parts)


WIDE_MAKERS = {"pedestrian": pedestrian_parts, "bicyclist": bicyclist_parts, "car": vehicle_parts}
