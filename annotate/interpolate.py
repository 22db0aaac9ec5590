"""Interpolation of keyframes into per-frame poses (pure functions, vectorised over frames).

Three interpolants, all exact at the keyframes:

- ``linear``: positions piecewise linear in the frame number, heading along the shortest arc
  between keyframe headings (what CVAT, Label Studio and SUSTechPOINTS do).
- ``hermite``: a cubic Hermite curve in the ground plane. At each keyframe the tangent points
  along the keyframe's heading (or against it where the road user drives backwards along the
  chord) and its length is the speed implied by the neighbouring keyframes: the mean of the
  two chord speeds, weighted by frames (the parabola through three keyframes); a keyframe next
  to a standing interval (a stop or a start) gets zero speed. Each end's tangent is then
  limited per interval so that the progress along the chord is monotone (Fritsch & Carlson
  1980: alpha, beta <= 3), hence the path never runs past the next keyframe and comes back.
  Heading between keyframes follows the curve's tangent (plus pi
  when reversing); where the road user stands, the shortest arc; where the curve nearly stops
  inside an interval (under ``SLOW`` of the chord's mean speed), a blend of the two.
- ``pchip``: positions by monotone cubic (PCHIP, scipy) per axis, heading along the shortest
  arc.

Frames are integers; keyframe frames must be strictly increasing. Positions (K, 2) metres,
headings (K,) radians counter-clockwise from +x.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from seg2pose.core.errors import InputError

METHODS = ("linear", "hermite", "pchip")
STILL = 0.01  # metres: a chord shorter than this is a road user standing still
FC_LIMIT = 3.0  # Fritsch-Carlson: tangent / chord slope at most 3 keeps a cubic monotone
SLOW = 0.1  # the curve's speed over the chord's mean speed below which the heading leans to the arc


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles (any shape) radians -> the same angles in [-pi, pi)."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def _locate(kf: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interval index i (Q,) with kf[i] <= q <= kf[i+1] and the fraction t (Q,) in [0, 1]."""
    i = np.clip(np.searchsorted(kf, q, side="right") - 1, 0, max(len(kf) - 2, 0))
    if len(kf) < 2:
        return i, np.zeros(len(q))
    span = (kf[i + 1] - kf[i]).astype(np.float64)
    return i, (q - kf[i]) / span


def shortest_arc(kf: np.ndarray, heading: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Headings (Q,) at frames q, linear along the shortest arc between keyframe headings."""
    if len(kf) == 1:
        return np.full(len(q), wrap_angle(heading[0]))
    unwrapped = np.unwrap(np.asarray(heading, dtype=np.float64))
    return wrap_angle(np.interp(q, kf, unwrapped))


def _check(kf: np.ndarray, xy: np.ndarray, heading: np.ndarray, q: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    kf = np.asarray(kf, dtype=np.int64).reshape(-1)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    heading = np.asarray(heading, dtype=np.float64).reshape(-1)
    q = np.asarray(q, dtype=np.int64).reshape(-1)
    if not (len(kf) == len(xy) == len(heading)) or len(kf) == 0:
        raise InputError(f"need matching keyframe frames, positions and headings, got "
                         f"{len(kf)}, {len(xy)}, {len(heading)}", field="keyframes")
    if np.any(np.diff(kf) <= 0):
        raise InputError("keyframe frames must be strictly increasing", field="keyframes")
    if len(q) and (q.min() < kf[0] or q.max() > kf[-1]):
        raise InputError(f"frames {q.min()}..{q.max()} reach outside the keyframes "
                         f"{kf[0]}..{kf[-1]}", field="frames")
    return kf, xy, heading, q


def interpolate(kf: np.ndarray, xy: np.ndarray, heading: np.ndarray, q: np.ndarray,
                method: str = "hermite") -> tuple[np.ndarray, np.ndarray]:
    """Poses at frames q (Q,) ints from keyframes at frames kf (K,) ints (strictly increasing,
    q within kf[0]..kf[-1]) with positions xy (K, 2) metres and headings (K,) radians.

    Returns positions (Q, 2) metres and headings (Q,) radians in [-pi, pi)."""
    if method not in METHODS:
        raise InputError(f"unknown interpolation {method!r}; known: {', '.join(METHODS)}",
                         field="interpolation")
    kf, xy, heading, q = _check(kf, xy, heading, q)
    if len(kf) == 1:
        return np.repeat(xy, len(q), axis=0), np.full(len(q), wrap_angle(heading[0]))
    if method == "linear":
        pos = np.column_stack([np.interp(q, kf, xy[:, 0]), np.interp(q, kf, xy[:, 1])])
        return pos, shortest_arc(kf, heading, q)
    if method == "pchip":
        pos = PchipInterpolator(kf, xy, axis=0)(q)
        k = np.clip(np.searchsorted(kf, q), 0, len(kf) - 1)
        exact = kf[k] == q  # PCHIP is exact at nodes up to rounding; make it bit-exact
        pos[exact] = xy[k[exact]]
        return pos, shortest_arc(kf, heading, q)
    return hermite(kf, xy, heading, q)


def hermite_tangents(kf: np.ndarray, xy: np.ndarray, heading: np.ndarray,
                     speeds: str = "bessel") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per interval (K-1 of them): start and end tangents (K-1, 2) in metres per unit of the
    interval parameter (0..1), and the direction of travel (K-1,) relative to the headings:
    +1 forwards at both ends, -1 backwards at both ends, 0 mixed (a reversal inside).

    speeds: "bessel" (the speed at a keyframe is the slope of the parabola through it and its
    neighbours: the frame-weighted mean of the two chord speeds) or "harmonic" (PCHIP's
    harmonic mean). Measured on synthetic traffic (benches/annotate_interp.py, tuning seeds),
    "bessel" is 10-20 % closer to the truth at 25 frames' spacing, and the Fritsch-Carlson
    limit keeps it from overshooting. Either way a keyframe next to a still chord (a stop or a
    start) gets zero speed."""
    chord = np.diff(xy, axis=0)                      # (K-1, 2)
    length = np.linalg.norm(chord, axis=1)
    dframes = np.diff(kf).astype(np.float64)
    speed = length / dframes                         # chord speeds, metres per frame
    # speed at each keyframe: harmonic mean of the neighbouring chord speeds (0 if either is 0)
    v = np.empty(len(kf))
    v[0], v[-1] = speed[0], speed[-1]
    a, b = speed[:-1], speed[1:]
    ha, hb = dframes[:-1], dframes[1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        if speeds == "harmonic":
            v[1:-1] = np.where((a > 0) & (b > 0), 2 * a * b / (a + b), 0.0)
        else:  # the parabola through three keyframes (frame-weighted mean, Bessel's tangent)
            v[1:-1] = (a * hb + b * ha) / (ha + hb)
    # a keyframe next to a still chord is a stop (or a start): zero speed there
    still_chord = length < STILL
    v[:-1][still_chord] = 0.0
    v[1:][still_chord] = 0.0
    u = np.column_stack([np.cos(heading), np.sin(heading)])  # (K, 2) heading directions
    with np.errstate(invalid="ignore", divide="ignore"):
        c_hat = np.where(length[:, None] > 0, chord / np.maximum(length, 1e-300)[:, None], 0.0)
    # per interval, each end's tangent points along +-heading, whichever goes along the chord
    dot0 = np.einsum("ik,ik->i", u[:-1], c_hat)
    dot1 = np.einsum("ik,ik->i", u[1:], c_hat)
    s0, s1 = np.where(dot0 < 0, -1.0, 1.0), np.where(dot1 < 0, -1.0, 1.0)
    # chord speeds are too slow on a bend: the tangents of a cubic that follows a circular arc
    # turning by theta are 4 tan(theta / 4) / (2 sin(theta / 2)) times the chord
    # (-> 1 for a straight interval; measured: 1 % closer to the truth at 25 frames' spacing)
    turn = np.clip(np.abs(wrap_angle(np.diff(heading))), 1e-6, 3.0)
    bend = 2 * np.tan(turn / 4) / np.sin(turn / 2)
    m0 = (s0 * v[:-1] * dframes * bend)[:, None] * u[:-1]
    m1 = (s1 * v[1:] * dframes * bend)[:, None] * u[1:]
    # Fritsch-Carlson on the progress along the chord: its end slopes alpha = m.c / L <= 3
    with np.errstate(invalid="ignore", divide="ignore"):
        alpha = np.einsum("ik,ik->i", m0, c_hat) / length
        beta = np.einsum("ik,ik->i", m1, c_hat) / length
        k0 = np.where(alpha > FC_LIMIT, FC_LIMIT / alpha, 1.0)
        k1 = np.where(beta > FC_LIMIT, FC_LIMIT / beta, 1.0)
    still = length < STILL
    m0 *= np.where(still, 0.0, k0)[:, None]
    m1 *= np.where(still, 0.0, k1)[:, None]
    direction = np.where(s0 == s1, s0, 0.0)
    return m0, m1, direction


def hermite(kf: np.ndarray, xy: np.ndarray, heading: np.ndarray, q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """The ``hermite`` interpolant (see the module docstring); arguments as ``interpolate``."""
    m0, m1, direction = hermite_tangents(kf, xy, heading)
    i, t = _locate(kf, q)
    t2, t3 = t * t, t * t * t
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
    p0, p1 = xy[i], xy[i + 1]
    pos = h00[:, None] * p0 + h10[:, None] * m0[i] + h01[:, None] * p1 + h11[:, None] * m1[i]
    # derivative w.r.t. t: its direction is the heading along the curve
    d00, d10, d01, d11 = 6 * t2 - 6 * t, 3 * t2 - 4 * t + 1, -6 * t2 + 6 * t, 3 * t2 - 2 * t
    vel = d00[:, None] * p0 + d10[:, None] * m0[i] + d01[:, None] * p1 + d11[:, None] * m1[i]
    along = np.arctan2(vel[:, 1], vel[:, 0]) + np.where(direction[i] < 0, np.pi, 0.0)
    length = np.linalg.norm(xy[1:] - xy[:-1], axis=1)
    # the tangent says nothing where the road user stands (still chord); a reversal inside the
    # interval: the tangent cannot tell forwards from backwards. The direction follows the
    # shortest arc there. Where the curve nearly stops inside an interval (both ends' tangents
    # at the Fritsch-Carlson limit make its progress 3 (2t - 1)^2 times the chord's: zero at
    # the middle) the tangent's direction is that of whatever sideways part is left, however
    # small -- up to 90 degrees off. So below SLOW of the chord's mean speed the heading is
    # blended towards the shortest arc, in proportion: continuous, and the tangent's wherever
    # the road user moves.
    speed = np.linalg.norm(vel, axis=1) / np.maximum(length[i], STILL)
    weight = np.clip(speed / SLOW, 0.0, 1.0)
    use_arc = (length[i] < STILL) | (direction[i] == 0)
    weight[use_arc] = 0.0
    hd = wrap_angle(along)
    blend = weight < 1.0
    if blend.any():
        arc = shortest_arc(kf, heading, q[blend])
        hd[blend] = wrap_angle(arc + weight[blend] * wrap_angle(hd[blend] - arc))
    # exact at keyframes
    exact = (t == 0) | (t == 1)
    k = i[exact] + (t[exact] == 1)
    pos[exact] = xy[k]
    hd[exact] = wrap_angle(heading[k])
    return pos, hd


# Per-class default interpolation, measured on synthetic scenes (docs/RESULTS.md, "Annotation:
# interpolation"); classes not listed use DEFAULT_METHOD.
CLASS_METHODS: dict[str, str] = {}  # hermite won for every class (pedestrians included)
DEFAULT_METHOD = "hermite"


def default_method(cls: str) -> str:
    """The interpolation a class uses unless its track chooses another."""
    return CLASS_METHODS.get(cls, DEFAULT_METHOD)
