"""Velocity and acceleration of every road user, estimated from its track.

The velocity at a frame is the least-squares slope of the positions over the trailing window
of ``window_s`` seconds (the frame and the ones before it, within the same track; fewer at a
track's start): what is known of the motion at that moment, which is what TTC's "continuing
at the current velocity" asks for. A constant velocity is reproduced exactly; noise of
sigma metres per frame leaves about sigma * sqrt(12 / n) / (n / fps) m/s for n frames in the
window. The acceleration is the same slope taken over the velocities (so it lags by about one
window). ``centred`` takes the window around the frame instead (no lag, but it sees the
future: a braking shows before it starts).

All functions work on ``Tracks`` rows (sorted by track, then frame) and are vectorised over
rows: a correlation with fixed weights where the frames of the window are consecutive, one
pass per frame of the window elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.safety.tracks import Tracks

BACKWARDS_MPS = 1e-6  # slower than this along the heading: not moving backwards


@dataclass(frozen=True)
class MotionOptions:
    """window_s: seconds of track the slopes are fitted over (at least 2 frames); centred:
    window around the frame instead of before it; moving_mps: below this speed a road user is
    standing (its heading, when the poses give none, is kept from when it last moved).
    The 1 s window was chosen on the tuning scene (synthetic seed 201, baseline tracks): the
    median error of min TTC against the truth's was 0.26 s with it, 0.59 s with 0.5 s."""

    window_s: float = 1.0
    centred: bool = False
    moving_mps: float = 0.5


@dataclass
class Motion:
    """Per row of a Tracks: vel (N, 2) m/s; speed (N,) m/s; acc (N, 2) m/s^2; along (N,)
    acceleration along the heading (negative: braking), m/s^2; lateral (N,) m/s^2 (positive:
    to the left); heading (N,) radians: the poses' where given, else the direction of motion."""

    vel: np.ndarray
    speed: np.ndarray
    acc: np.ndarray
    along: np.ndarray
    lateral: np.ndarray
    heading: np.ndarray


def window_frames(fps: float, opts: MotionOptions) -> int:
    return max(2, int(round(opts.window_s * fps)) + (0 if opts.centred else 1))


def slope(tracks: Tracks, values: np.ndarray, n: int, centred: bool = False) -> np.ndarray:
    """(N, k) least-squares slope per second of ``values`` (N, k) over the ``n`` rows ending at
    each row (``centred``: around it) within its track, using the rows' times (gaps are
    fine). A row alone in its track gets 0.

    Where the window is whole and its frames consecutive (all but a track's first frames and
    the frames next to a gap), the times are k / fps for fixed k, so the slope is a fixed
    weighting of the values, fps * sum((k - mean k) v_k) / sum((k - mean k)^2): one
    correlation per column (``np.correlate``) instead of a pass per frame of the window. The
    other rows are fitted from their own times (``_slope_rows``). Both are the same least-
    squares slope; they differ by rounding (below 1e-9 m/s, tests/seg2pose/safety)."""
    values = np.asarray(values, np.float64).reshape(len(tracks), -1)
    N = len(tracks)
    lo_k, hi_k = (-(n // 2), n - n // 2 - 1) if centred else (-(n - 1), 0)
    idx = np.arange(N)
    out = np.zeros_like(values)
    if N == 0:
        return out
    starts, ends = tracks.starts(), tracks.ends()
    jl, jh = idx + lo_k, idx + hi_k
    regular = (jl >= starts) & (jh <= ends)
    f = tracks.frame
    regular &= (f[np.clip(jh, 0, N - 1)] - f[np.clip(jl, 0, N - 1)]) == hi_k - lo_k
    reg = np.flatnonzero(regular)
    if len(reg):
        k = np.arange(lo_k, hi_k + 1, dtype=np.float64)
        kc = k - k.mean()
        w = kc * (tracks.fps / float(kc @ kc))
        for c in range(values.shape[1]):
            # full[p] = sum_m w[m] values[p + m]: the window of rows p .. p + n - 1, row p - lo_k
            full = np.correlate(values[:, c], w, "valid")
            out[reg, c] = full[reg + lo_k]
    irr = np.flatnonzero(~regular)
    if len(irr):
        out[irr] = _slope_rows(tracks, values, n, centred, irr)
    return out


def _slope_rows(tracks: Tracks, values: np.ndarray, n: int, centred: bool,
                rows: np.ndarray) -> np.ndarray:
    """(R, k) the slope of ``slope`` at ``rows`` (R,), fitted from the rows' own times: one
    pass per frame of the window."""
    t = tracks.t
    lo_row, hi_row = tracks.starts()[rows], tracks.ends()[rows]
    R = len(rows)
    t_r = t[rows]
    offs = range(-(n // 2), n - n // 2) if centred else range(-(n - 1), 1)
    s1 = np.zeros(R)
    st = np.zeros(R)
    stt = np.zeros(R)
    sv = np.zeros((R, values.shape[1]))
    stv = np.zeros((R, values.shape[1]))
    for k in offs:
        j = rows + k
        ok = (j >= lo_row) & (j <= hi_row)
        j = np.where(ok, j, rows)
        w = ok.astype(np.float64)
        tau = (t[j] - t_r) * w  # times relative to the row: no loss of precision late in a video
        s1 += w
        st += tau
        stt += tau * tau
        vj = np.take(values, j, axis=0)
        sv += vj * w[:, None]
        stv += vj * tau[:, None]
    den = s1 * stt - st * st
    num = s1[:, None] * stv - st[:, None] * sv
    out = np.zeros((R, values.shape[1]))
    good = den > 1e-12
    out[good] = num[good] / den[good][:, None]
    return out


def fill_heading(tracks: Tracks, vel: np.ndarray, speed: np.ndarray, moving_mps: float) -> np.ndarray:
    """The poses' headings where known; elsewhere the direction of motion, carried forward
    (then backward) through a track's standing still. NaN only for a track that never moves
    and has no heading (its footprint then lies along +x)."""
    h = tracks.heading.copy()
    motion = np.arctan2(vel[:, 1], vel[:, 0])
    unknown = ~np.isfinite(h)
    use = unknown & (speed >= moving_mps)
    h[use] = motion[use]
    missing = ~np.isfinite(h)
    if missing.any():
        starts = tracks.starts()
        ends = tracks.ends()
        idx = np.arange(len(h))
        have = np.where(~missing, idx, -1)
        prev = np.maximum.accumulate(have)  # last known at or before the row
        prev = np.where(prev >= starts, prev, -1)
        nxt = np.where(~missing, idx, len(h))[::-1]
        nxt = np.minimum.accumulate(nxt)[::-1]
        nxt = np.where(nxt <= ends, nxt, -1)
        pick = np.where(prev >= 0, prev, nxt)
        h = np.where(missing & (pick >= 0), h[np.maximum(pick, 0)], h)
    return np.where(np.isfinite(h), h, 0.0)


def motion(tracks: Tracks, opts: MotionOptions = MotionOptions()) -> Motion:
    """Velocities, speeds, accelerations and headings of every row."""
    n = window_frames(tracks.fps, opts)
    vel = slope(tracks, tracks.xy, n, opts.centred)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    acc = slope(tracks, vel, n, opts.centred)
    heading = fill_heading(tracks, vel, speed, opts.moving_mps)
    d = np.c_[np.cos(heading), np.sin(heading)]
    along = (acc * d).sum(axis=1)
    lateral = acc[:, 1] * d[:, 0] - acc[:, 0] * d[:, 1]
    # moving backwards (a reversing car, or a heading 180 degrees off): braking is against the
    # direction of motion, not the heading. Standing still (exact tracks: a velocity of 0 up to
    # rounding, whose sign the fit's rounding would decide) counts as forward
    backwards = (vel * d).sum(axis=1) < -BACKWARDS_MPS
    along = np.where(backwards, -along, along)
    return Motion(vel, speed, acc, along, lateral, heading)
