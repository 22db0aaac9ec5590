"""Velocity and acceleration of every road user at every frame, from its whole track (offline
analysis: no lag).

**Noise model.** A track's positions are the true ground positions plus white noise of
standard deviation sigma metres per axis (the same over the track), the motion itself smooth
(bounded jerk). sigma is measured per track (per segment without a gap) from the third
differences of its positions: at the frame rate of video the motion's own third difference
(jerk x dt^3) is below a millimetre, so d3 = x[k+3] - 3x[k+2] + 3x[k+1] - x[k] is noise of
variance 20 sigma^2; sigma = 1.4826 median(|d3|) / sqrt(20) over both axes (robust to the
few frames where the motion itself changes).

**Smoother.** At each frame a quadratic is fitted by least squares to the n frames centred on
it (local polynomial regression, Savitzky and Golay 1964); its first and second derivative
there are the velocity and the acceleration. A centred window has no lag: a constant
acceleration is reproduced exactly, at every frame. The width follows the track's noise: the
velocity's n_v is the smallest (odd, at least ``min_frames``) with a velocity noise
sigma fps sqrt(12 / (n (n^2 - 1))) <= ``speed_sd_mps``, the acceleration's n_a the smallest
with 2 sigma fps^2 / sqrt(S4 - S2^2 / n) <= ``acc_sd_mps2`` (S2, S4: sums of k^2, k^4 over the
window), both at most ``max_window_s``. An exact track gets the narrowest window (a sudden
change is spread over ``min_frames`` frames); a track with 0.3 m noise about 1 s for the
velocity, 1.7 s for the acceleration. Near a segment's ends the window is shifted inside it
(the same n frames, the fit evaluated off centre).

Measured against the alternative, an RTS (Kalman) smoother with a constant-acceleration model
and the same per-track noise, in docs/RESULTS.md ("Traffic conflicts").

All functions work on ``Tracks`` rows (sorted by track, then frame) and are vectorised over
rows: a correlation with fixed weights where the window's frames are consecutive, a per-row
fit elsewhere (track ends). Gaps are the caller's (``gaps.fill_gaps``): a window never
reaches over a missing frame (a segment ends there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.safety.tracks import Tracks

MAD = 1.4826  # median absolute deviation -> standard deviation (Gaussian)


@dataclass(frozen=True)
class MotionOptions:
    """speed_sd_mps, acc_sd_mps2: the noise the velocity and acceleration may keep (they set
    each track's window); min_frames: the narrowest window (odd, >= 3); max_window_s: the
    widest; window_s: a fixed width in seconds for every track instead (None: from the
    noise); moving_mps: below this speed a road user is standing (its heading, when the
    poses give none, is kept from when it last moved)."""

    speed_sd_mps: float = 0.15
    acc_sd_mps2: float = 0.5
    min_frames: int = 5
    max_window_s: float = 2.5
    window_s: float | None = None
    moving_mps: float = 0.5


@dataclass
class Motion:
    """Per row of a Tracks: vel (N, 2) m/s; speed (N,) m/s; acc (N, 2) m/s^2; along (N,)
    acceleration along the direction of travel (negative: braking), m/s^2; lateral (N,)
    m/s^2 (positive: to the left); heading (N,) radians: the poses' where given, else the
    direction of motion; sigma (N,) the track's position noise, metres; n_vel, n_acc (N,)
    the windows used, frames."""

    vel: np.ndarray
    speed: np.ndarray
    acc: np.ndarray
    along: np.ndarray
    lateral: np.ndarray
    heading: np.ndarray
    sigma: np.ndarray
    n_vel: np.ndarray
    n_acc: np.ndarray


def segments(tracks: Tracks) -> tuple[np.ndarray, np.ndarray]:
    """(N,) index of the first and last row of each row's segment: a run of consecutive
    frames of one track (a missing frame ends a segment)."""
    n = len(tracks)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    new = np.r_[True, (tracks.track_id[1:] != tracks.track_id[:-1]) | (np.diff(tracks.frame) != 1)]
    idx = np.arange(n)
    starts = np.maximum.accumulate(np.where(new, idx, 0))
    last = np.r_[new[1:], True]
    ends = np.minimum.accumulate(np.where(last, idx, n)[::-1])[::-1]
    return starts, ends


def noise_sigma(tracks: Tracks, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """(N,) each row's segment's position noise, metres (the module's noise model, from the
    median absolute third difference: sigma = 1.4826 median|d3| / sqrt(20), robust to the few
    frames where the motion itself changes: a turn's start, a braking's onset); 0 for a
    segment of fewer than 4 frames."""
    n = len(tracks)
    out = np.zeros(n)
    if n < 4:
        return out
    xy = tracks.xy
    d3 = np.abs(xy[3:] - 3 * xy[2:-1] + 3 * xy[1:-2] - xy[:-3])  # rows k .. k + 3
    heads = np.flatnonzero(np.r_[True, starts[1:] != starts[:-1]])
    for s0 in heads:  # segments are contiguous runs of rows: one median each
        e0 = int(ends[s0])
        if e0 - s0 >= 3:
            out[s0:e0 + 1] = MAD * float(np.median(d3[s0:e0 - 2])) / np.sqrt(20.0)
    return out


def _sums(n: np.ndarray):
    h = (n - 1) / 2
    s2 = h * (h + 1) * (2 * h + 1) / 3
    s4 = h * (h + 1) * (2 * h + 1) * (3 * h * h + 3 * h - 1) / 15
    return s2, s4


def window_sizes(sigma: np.ndarray, fps: float, opts: MotionOptions) -> tuple[np.ndarray, np.ndarray]:
    """(N,) odd window widths in frames for the velocity and the acceleration (the module's
    rule), from each row's noise ``sigma`` (N,) metres."""
    lo = max(3, opts.min_frames | 1)
    hi = max(lo, int(opts.max_window_s * fps) | 1)
    if opts.window_s is not None:
        n = np.full(len(sigma), max(lo, int(round(opts.window_s * fps)) | 1))
        return n, n
    cand = np.arange(lo, hi + 1, 2, dtype=np.float64)
    s2, s4 = _sums(cand)
    v_sd = np.sqrt(12.0 / (cand * (cand * cand - 1))) * fps  # per metre of sigma
    a_sd = 2.0 * fps * fps / np.sqrt(s4 - s2 * s2 / cand)
    values, inv = np.unique(np.asarray(sigma, np.float64), return_inverse=True)  # one per segment
    sig = values[:, None]

    def pick(sd, target):
        ok = sig * sd[None, :] <= target
        first = np.where(ok.any(axis=1), ok.argmax(axis=1), len(cand) - 1)
        return cand[first].astype(np.int64)[inv.reshape(-1)]

    return pick(v_sd, opts.speed_sd_mps), pick(a_sd, opts.acc_sd_mps2)


def derivative(tracks: Tracks, values: np.ndarray, n: np.ndarray, order: int,
               bounds: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(N, k) the ``order``-th derivative (1 or 2) per second of ``values`` (N, k) at each row,
    from the quadratic fitted to the ``n`` (N,) odd frames around it (shifted inside its
    segment near the ends; a segment shorter than 3 frames: 0, or the slope of 2); order 0:
    the fitted value itself (the smoothed positions)."""
    values = np.asarray(values, np.float64).reshape(len(tracks), -1)
    N = len(tracks)
    out = np.zeros_like(values)
    if N == 0:
        return out
    starts, ends = segments(tracks) if bounds is None else bounds
    n = np.asarray(n, np.int64)
    h = n // 2
    idx = np.arange(N)
    regular = (idx - h >= starts) & (idx + h <= ends)
    fps = tracks.fps
    for w in np.unique(n[regular]):
        rows = np.flatnonzero(regular & (n == w))
        hw = int(w) // 2
        k = np.arange(-hw, hw + 1, dtype=np.float64)
        if order == 0:
            s2, s4 = float((k ** 2).sum()), float((k ** 4).sum())
            wts = (s4 - s2 * k * k) / (w * s4 - s2 * s2)
        elif order == 1:
            wts = k * fps / float(k @ k)
        else:
            s2, s4 = float((k ** 2).sum()), float((k ** 4).sum())
            wts = 2.0 * (k * k - s2 / w) / (s4 - s2 * s2 / w) * fps * fps
        lo, hi = int(rows.min()) - hw, int(rows.max()) + hw
        for c in range(values.shape[1]):
            full = np.correlate(values[lo:hi + 1, c], wts, "valid")  # full[p]: rows lo+p .. lo+p+w-1
            out[rows, c] = full[rows - hw - lo]
    irr = np.flatnonzero(~regular)
    if len(irr):
        out[irr] = _fit_rows(tracks, values, n[irr], order, irr, starts[irr], ends[irr])
    return out


def _fit_rows(tracks: Tracks, values: np.ndarray, n: np.ndarray, order: int, rows: np.ndarray,
              lo_row: np.ndarray, hi_row: np.ndarray) -> np.ndarray:
    """``derivative`` at ``rows`` whose window does not fit centred: the n frames of the
    segment nearest to centred, a quadratic fitted on the rows' own times (a line where the
    segment has 2 frames; 0 where it has 1)."""
    t = tracks.t
    length = hi_row - lo_row + 1
    m = np.minimum(n, length)
    first = np.clip(rows - m // 2, lo_row, hi_row - m + 1)
    M = int(m.max())
    R = len(rows)
    S = np.zeros((R, 5))
    Sv = np.zeros((R, 3, values.shape[1]))
    for j in range(M):
        r = first + j
        w = (j < m).astype(np.float64)
        r = np.where(j < m, r, rows)
        tau = (t[r] - t[rows]) * w
        p = np.stack([np.ones(R), tau, tau ** 2, tau ** 3, tau ** 4], 1) * w[:, None]
        S += p
        Sv += p[:, :3, None] * values[r][:, None, :]
    deg = np.where(m >= 3, 2, np.where(m == 2, 1, 0))
    out = np.zeros((R, values.shape[1]))
    q = deg == 2
    if q.any():
        A = np.stack([S[q][:, i:i + 3] for i in range(3)], 1)  # (Q, 3, 3) moments
        coef = np.linalg.solve(A, Sv[q])  # (Q, 3, k): c0 + c1 tau + c2 tau^2
        out[q] = coef[:, order] * (2.0 if order == 2 else 1.0)
    ln = deg == 1
    if ln.any() and order < 2:
        den = (S[ln, 0] * S[ln, 2] - S[ln, 1] ** 2)[:, None]
        out[ln] = ((S[ln, 0][:, None] * Sv[ln, 1] - S[ln, 1][:, None] * Sv[ln, 0]) / den if order == 1
                   else (S[ln, 2][:, None] * Sv[ln, 0] - S[ln, 1][:, None] * Sv[ln, 1]) / den)
    if order == 0:
        out[deg == 0] = values[rows[deg == 0]]
    return out


def fill_heading(tracks: Tracks, vel: np.ndarray, speed: np.ndarray, moving_mps: float) -> np.ndarray:
    """The poses' headings where known; elsewhere the direction of motion (the smoothed
    velocity's: it turns with a turning road user, without lag), carried forward (then
    backward) through a track's standing still. 0 for a track that never moves and has no
    heading (its footprint then lies along +x)."""
    h = tracks.heading.copy()
    motion_dir = np.arctan2(vel[:, 1], vel[:, 0])
    unknown = ~np.isfinite(h)
    use = unknown & (speed >= moving_mps)
    h[use] = motion_dir[use]
    missing = ~np.isfinite(h)
    if missing.any():
        starts, ends = tracks.starts(), tracks.ends()
        idx = np.arange(len(h))
        prev = np.maximum.accumulate(np.where(~missing, idx, -1))
        prev = np.where(prev >= starts, prev, -1)
        nxt = np.minimum.accumulate(np.where(~missing, idx, len(h))[::-1])[::-1]
        nxt = np.where(nxt <= ends, nxt, -1)
        pick = np.where(prev >= 0, prev, nxt)
        h = np.where(missing & (pick >= 0), h[np.maximum(pick, 0)], h)
    return np.where(np.isfinite(h), h, 0.0)


def motion(tracks: Tracks, opts: MotionOptions = MotionOptions()) -> Motion:
    """Velocities, speeds, accelerations and headings of every row (the module's smoother)."""
    bounds = segments(tracks)
    sigma = noise_sigma(tracks, *bounds)
    n_v, n_a = window_sizes(sigma, tracks.fps, opts)
    vel = derivative(tracks, tracks.xy, n_v, 1, bounds)
    acc = derivative(tracks, tracks.xy, n_a, 2, bounds)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    heading = fill_heading(tracks, vel, speed, opts.moving_mps)
    # along / across the direction of travel where moving (a pose heading may be off by
    # 180 degrees or lag a turn); the heading where standing
    moving = speed >= opts.moving_mps
    safe = np.maximum(speed, 1e-12)
    d = np.where(moving[:, None], vel / safe[:, None], np.c_[np.cos(heading), np.sin(heading)])
    along = (acc * d).sum(axis=1)
    lateral = acc[:, 1] * d[:, 0] - acc[:, 0] * d[:, 1]
    return Motion(vel, speed, acc, along, lateral, heading, sigma, n_v, n_a)
