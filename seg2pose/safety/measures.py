"""SSAM's measures of a conflict beyond TTC and PET (Gettman and Head 2008, FHWA-HRT-08-050,
"Surrogate Safety Assessment Model and Validation: Final Report", table 1), vectorised over
K conflicts: the conflict angle and type, MaxDeltaV, the gap between two footprints.

- **Conflict angle**: the angle from the first road user's direction of travel to the
  second's (SSAM: "the approximate angle of the hypothetical collision"), in degrees in
  (-180, 180], positive when the second's direction is turned counter-clockwise from the
  first's; at the minimum-TTC frame (else the PET frames, else the closest approach).
- **Type** (SSAM): rear-end when |angle| < 30 degrees, lane change when < 85, crossing
  above; here also head-on at >= 150 degrees (SSAM counts those as crossing) and, because a
  safety study sorts them first, "pedestrian" / "bicyclist" when one road user is one (the
  angle's type is kept in ``ssam_type``).
- **MaxDeltaV**: the larger change of velocity of the two in a perfectly inelastic
  collision at the minimum-TTC velocities: DeltaV_a = m_b / (m_a + m_b) |v_a - v_b|; masses
  by class (``CLASS_MASS_KG``).
"""

from __future__ import annotations

import numpy as np

from seg2pose.safety.footprints import overlaps

VULNERABLE = ("pedestrian", "bicyclist")
# typical masses with their riders / drivers, kg (a pedestrian 75, a bicycle 15 with its rider)
CLASS_MASS_KG = {"car": 1500.0, "pedestrian": 75.0, "bicyclist": 90.0, "truck": 12000.0,
                 "bus": 15000.0, "motorcycle": 280.0, "moped": 180.0}
UNKNOWN_MASS_KG = CLASS_MASS_KG["car"]
REAR_END_DEG, LANE_CHANGE_DEG, HEAD_ON_DEG = 30.0, 85.0, 150.0


def conflict_angle(dir_a: np.ndarray, dir_b: np.ndarray) -> np.ndarray:
    """(K,) degrees in (-180, 180]: from direction ``dir_a`` to ``dir_b`` (K,) radians,
    counter-clockwise positive."""
    d = np.degrees(np.angle(np.exp(1j * (np.asarray(dir_b, float) - np.asarray(dir_a, float)))))
    return np.where(d <= -180.0, 180.0, d)


def angle_type(angle_deg) -> np.ndarray:
    """(K,) SSAM's type from the conflict angle: rear-end (< 30 degrees), lane-change (< 85),
    crossing, head-on (>= 150); "unknown" where the angle is."""
    a = np.abs(np.asarray(angle_deg, float))
    out = np.select([a < REAR_END_DEG, a < LANE_CHANGE_DEG, a < HEAD_ON_DEG],
                    ["rear-end", "lane-change", "crossing"], "head-on").astype(object)
    out[~np.isfinite(a)] = "unknown"
    return out


def classify(cls_a, cls_b, angle_deg) -> np.ndarray:
    """(K,) conflict types: "pedestrian" / "bicyclist" when one road user is one (a
    pedestrian first), else ``angle_type``."""
    out = angle_type(angle_deg)
    ca = np.char.lower(np.asarray(cls_a, str))
    cb = np.char.lower(np.asarray(cls_b, str))
    for v in VULNERABLE[::-1]:
        out[(ca == v) | (cb == v)] = v
    return out


def masses(cls) -> np.ndarray:
    """(K,) kg by class name (a class not in CLASS_MASS_KG: a car's)."""
    return np.array([CLASS_MASS_KG.get(str(c).lower(), UNKNOWN_MASS_KG) for c in cls], float)


def max_delta_v(cls_a, cls_b, delta_s) -> np.ndarray:
    """(K,) m/s: SSAM's MaxDeltaV from the classes' masses and |v_a - v_b| (K,)."""
    ma, mb = masses(cls_a), masses(cls_b)
    return np.maximum(mb, ma) / (ma + mb) * np.asarray(delta_s, float)


def _point_to_rect(px, py, cx, cy, c, s, hl, hw):
    """(M,) distance of points (px, py) to rectangles centred (cx, cy), heading cos/sin (c, s),
    half length / width."""
    dx, dy = px - cx, py - cy
    u = np.abs(dx * c + dy * s) - hl
    v = np.abs(-dx * s + dy * c) - hw
    return np.hypot(np.maximum(u, 0.0), np.maximum(v, 0.0))


def footprint_gap(xy_a, heading_a, size_a, xy_b, heading_b, size_b) -> np.ndarray:
    """(M,) metres between two footprints (oriented rectangles; 0 where they overlap): for two
    convex polygons apart, the least distance is from a corner of one to the other."""
    xy_a, xy_b = np.asarray(xy_a, float).reshape(-1, 2), np.asarray(xy_b, float).reshape(-1, 2)
    size_a, size_b = np.asarray(size_a, float).reshape(-1, 2), np.asarray(size_b, float).reshape(-1, 2)
    ha, hb = np.asarray(heading_a, float), np.asarray(heading_b, float)
    best = np.full(len(xy_a), np.inf)
    for (p, hp, sp), (q, hq, sq) in (((xy_a, ha, size_a), (xy_b, hb, size_b)),
                                     ((xy_b, hb, size_b), (xy_a, ha, size_a))):
        c, s = np.cos(hp), np.sin(hp)
        cq, sq_ = np.cos(hq), np.sin(hq)
        for fl, fw in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            px = p[:, 0] + fl * c * sp[:, 0] / 2 - fw * s * sp[:, 1] / 2
            py = p[:, 1] + fl * s * sp[:, 0] / 2 + fw * c * sp[:, 1] / 2
            np.minimum(best, _point_to_rect(px, py, q[:, 0], q[:, 1], cq, sq_, sq[:, 0] / 2, sq[:, 1] / 2),
                       out=best)
    return np.where(overlaps(xy_a, ha, size_a, xy_b, hb, size_b), 0.0, best)


def second_road_user(xy_a, vel_a, xy_b, vel_b) -> np.ndarray:
    """(K,) bool, True where b is SSAM's "second vehicle" (the one arriving later, that runs
    into the other): the one moving faster towards the other's centre."""
    r = np.asarray(xy_b, float) - np.asarray(xy_a, float)
    a_in = (np.asarray(vel_a, float) * r).sum(axis=1)   # a towards b
    b_in = -(np.asarray(vel_b, float) * r).sum(axis=1)  # b towards a
    return b_in > a_in
