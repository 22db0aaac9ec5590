"""Error intervals of the indicators: a parametric bootstrap of each conflict's two tracks.

**Error model.** A pose's error is two parts, per axis. A *fast* part, measured on the track
itself: the residuals of the track from its smoothed self (below), their standard deviation
sigma_f and lag-1 autocorrelation rho_f (``fast_errors``; 0 is white noise), drawn as an
AR(1) process e_k = rho e_(k-1) + sqrt(1 - rho^2) z_k with rho = rho_f. A *slow* part that
persists over seconds (the same mask errors from frame to frame: a wrong height, a shadow),
an AR(1) with correlation time ``corr_s`` (rho = exp(-dt / corr_s)) and standard deviation
sigma_c. The two add up to the pose's error radius ``r90_m`` = R: its true position is within
R metres with 90 % probability, an isotropic 2D Gaussian of sigma = R / sqrt(2 ln 10) =
R / 2.146 per axis, so sigma_c^2 = max(sigma^2 - sigma_f^2, 0). A track cannot tell its slow
error from its motion, so the slow part's size comes from r90 (calibrated against the truth on
other scenes, ``s2p calibrate-errors``) and its correlation time from tuning scenes. The
baseline's errors on synthetic seed 201 are such a mix: their autocorrelation falls to 0.6
within 0.5 s (the fast part) and stays near 0.4 for seconds (the slow part).

**Bootstrap.** The model world is the smoothed tracks (the local quadratic fit's values,
``kinematics.derivative`` of order 0, over ``model_window_s`` or the track's acceleration
window if wider): each draw adds errors from the model to it, and every indicator is computed
on the draw as on the tracks (velocities re-estimated, TTC, TA and PET searched over the whole
time both exist). Draw 0 has no error: its indicator theta_0 is the model world's "truth", and
the draws' deviations d = theta_d - theta_0 stand for the estimate's deviation from the truth
(minima over noisy frames included: they are biased low in the draws as in the estimate). The
interval is the basic bootstrap interval [theta - q_hi, theta - q_lo] of the deviations'
central ``level`` (where draw 0 has no such indicator, of the draws' deviations from the
estimate), widened ``spread`` times about the deviations' median, at least 0. The smoothed
world is smoother than the real one (a sudden braking in it is already spread out, and the
smoother's own bias at such a change does not show in the draws), so the raw bootstrap
intervals are too narrow; ``spread`` (per indicator: min TTC, TA, PET) was chosen so that 90 %
intervals hold the truth 90 % of the time on tuning data (docs/RESULTS.md, "Traffic
conflicts"). ``*_found_share`` says in how many draws the indicator exists at all (a draw with
no collision course has no TTC).

Only the encounter's own frames (with a margin for the velocity window) are redrawn, so this
costs little per conflict. PET is searched in each draw as the table searches it, over the
whole encounter (``pet.pet``; the draws set apart in time so that they never meet).
Measured coverage: benches/conflicts_noise.py and benches/conflicts_accuracy.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from seg2pose.safety.evasive import onsets, time_to_accident
from seg2pose.safety.footprints import overlaps
from seg2pose.safety.kinematics import derivative, motion
from seg2pose.safety.pet import closest_in_time, pet, refine
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc

SIGMA_PER_R90 = 1.0 / np.sqrt(2.0 * np.log(10.0))
SIGMA_PER_HEADING90 = 1.0 / 1.6449  # |N(0, sigma)| is below 1.645 sigma 90 % of the time


@dataclass(frozen=True)
class IntervalOptions:
    """draws: samples per conflict; corr_s: correlation time of the slow part of pose errors,
    seconds (the module's error model); level: the interval's coverage; pet_search_s: None
    (the default): PET searched over the whole encounter, as in the table; a number: only
    this close to the nominal frames; seed: of the draws (the same seed gives the same
    intervals); spread: the widening of the min TTC, TA and PET intervals (the module's
    bootstrap); model_window_s: the model world's smoothing; details: also return each
    interval's centre and half widths before the widening (``_put``). The defaults of
    corr_s and spread were chosen on tuning data (synthetic seed 201's runs and
    benches/conflicts_noise.py's seed 0), docs/RESULTS.md, "Traffic conflicts"."""

    draws: int = 200
    corr_s: float = 3.0
    level: float = 0.9
    pet_search_s: float | None = None
    seed: int = 0
    spread: tuple[float, float, float] = (2.1, 2.7, 2.2)
    model_window_s: float = 2.5
    details: bool = False


def ar1_noise(n: int, draws: int, rho: float, rng: np.random.Generator) -> np.ndarray:
    """(draws, n, 2) stationary AR(1) noise of unit variance."""
    z = rng.standard_normal((draws, n, 2))
    z[:, 0] /= np.sqrt(max(1.0 - rho * rho, 1e-12))  # start in the stationary distribution
    return lfilter([np.sqrt(1.0 - rho * rho)], [1.0, -rho], z, axis=1)


def fast_errors(tracks: Tracks, resid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) per row its track's fast error: the standard deviation per axis of the residuals
    ``resid`` (N, 2) from the smoothed track, and their lag-1 autocorrelation (0: white; in
    [0, 0.99]), over consecutive frames of the track."""
    tid = tracks.track_id
    ids, inv = np.unique(tid, return_inverse=True)
    inv = inv.reshape(-1)
    n = np.bincount(inv, minlength=len(ids)).astype(np.float64)
    ss = np.bincount(inv, (resid ** 2).sum(axis=1), minlength=len(ids))
    nxt = np.r_[(tid[1:] == tid[:-1]) & (np.diff(tracks.frame) == 1), False]
    lag = np.r_[(resid[:-1] * resid[1:]).sum(axis=1), 0.0] * nxt
    sl = np.bincount(inv, lag, minlength=len(ids))
    s0 = np.bincount(inv, (resid ** 2).sum(axis=1) * nxt, minlength=len(ids))
    sigma = np.sqrt(ss / np.maximum(2 * n, 1))
    rho = np.clip(np.divide(sl, s0, out=np.zeros(len(ids)), where=s0 > 0), 0.0, 0.99)
    return sigma[inv], rho[inv]


def _common_frames(tracks: Tracks, a: int, b: int, extra: int) -> tuple[int, int]:
    """The first and last frame at which both tracks exist, widened by ``extra`` frames."""
    fa = tracks.frame[_span(tracks, a)]
    fb = tracks.frame[_span(tracks, b)]
    return max(int(fa.min()), int(fb.min())) - extra, min(int(fa.max()), int(fb.max())) + extra


def _span(tracks: Tracks, track: int) -> slice:
    """The rows of ``track`` (rows are sorted by track id)."""
    tid = tracks.track_id
    return slice(int(np.searchsorted(tid, track, "left")), int(np.searchsorted(tid, track, "right")))


def _rows_of(tracks: Tracks, track: int, f0: int, f1: int) -> np.ndarray:
    sp = _span(tracks, track)
    f = tracks.frame[sp]
    return sp.start + np.flatnonzero((f >= f0) & (f <= f1))


def conflict_intervals(tracks: Tracks, table, opts, iopts: IntervalOptions = IntervalOptions(),
                       r90: np.ndarray | None = None, progress=None,
                       heading90: np.ndarray | None = None) -> dict:
    """INTERVAL_COLUMNS for each row of ``table`` (a ConflictTable of ``tracks``), (K,) arrays,
    by the module's bootstrap. ``r90``: (N,) metres per row of ``tracks`` (default
    ``tracks.r90``); rows with NaN get no error (a pair with none: no interval).
    ``heading90``: (N,) radians per row, the heading error 90 % of the poses stay within
    (None: headings not perturbed; drawn after the positions, with the slow part's
    correlation, so the position draws do not change). ``opts``: the ConflictOptions the
    table was made with."""
    r90 = tracks.r90 if r90 is None else r90
    K = len(table)
    out = {k: np.full(K, np.nan) for k in ("min_ttc_lo_s", "min_ttc_hi_s", "pet_lo_s", "pet_hi_s",
                                           "ta_lo_s", "ta_hi_s", "ttc_found_share", "pet_found_share")}
    if r90 is None or K == 0:
        return out
    c = table.columns
    fps = tracks.fps
    # the model world: each track smoothed over its velocity window; the fast part of its
    # error from the residuals
    mot0 = motion(tracks, opts.motion)
    smooth = derivative(tracks, tracks.xy, np.maximum(mot0.n_acc, int(iopts.model_window_s * fps) | 1), 0)
    sig_f_all, rho_f_all = fast_errors(tracks, tracks.xy - smooth)
    sig_all = r90 * SIGMA_PER_R90
    sig_f_all = np.where(np.isfinite(sig_all), np.minimum(sig_f_all, np.nan_to_num(sig_all)), 0.0)
    sig_c_all = np.sqrt(np.maximum(np.nan_to_num(sig_all) ** 2 - sig_f_all ** 2, 0.0))
    margin = int(np.ceil(opts.motion.max_window_s * fps)) + 2
    rho = float(np.exp(-1.0 / (fps * iopts.corr_s)))
    q = (100 * (1 - iopts.level) / 2, 100 * (1 + iopts.level) / 2)
    search = None if iopts.pet_search_s is None else int(round(iopts.pet_search_s * fps))
    it = range(K) if progress is None else progress(range(K))
    for k in it:
        rng = np.random.default_rng([iopts.seed, int(c["track_a"][k]), int(c["track_b"][k])])
        # the two tracks while both exist (and PET's window either side): the draws search
        # TTC, PET and TA over the whole time the two could meet, as the table did
        f0, f1 = _common_frames(tracks, int(c["track_a"][k]), int(c["track_b"][k]),
                                int(np.ceil(opts.pet_s * fps)))
        f0, f1 = min(f0, int(c["first_frame"][k])) - margin, max(f1, int(c["last_frame"][k])) + margin
        rows = np.r_[_rows_of(tracks, c["track_a"][k], f0, f1), _rows_of(tracks, c["track_b"][k], f0, f1)]
        sub = tracks.take(rows)
        if not np.isfinite(r90[rows]).any():
            continue  # no uncertainty known: no interval (not one of zero width)
        # rows: a's then b's, as sub sorts them
        sig_f, sig_c = sig_f_all[rows], sig_c_all[rows]
        D = iopts.draws + 1  # draw 0: the model world without error
        # one Tracks with D copies of the pair, copy d's ids offset so they stay apart
        counts = [int((sub.track_id == tr).sum()) for tr in np.unique(sub.track_id)]
        firsts = np.r_[0, np.cumsum(counts)[:-1]]
        slow = np.concatenate([ar1_noise(m, D, rho, rng) for m in counts], axis=1)
        fast = np.concatenate([ar1_noise(m, D, float(rho_f_all[rows][f]), rng) for m, f in zip(counts, firsts)],
                              axis=1)
        noise = slow * sig_c[None, :, None] + fast * sig_f[None, :, None]
        noise[0] = 0.0
        xy = smooth[rows][None] + noise
        heading = np.tile(sub.heading, D)
        if heading90 is not None:
            hn = np.concatenate([ar1_noise(m, D, rho, rng)[..., 0] for m in counts], axis=1)
            hn[0] = 0.0
            heading = (sub.heading[None] + hn * np.nan_to_num(heading90[rows] * SIGMA_PER_HEADING90)[None]).ravel()
        off = (np.arange(D) * 4)[:, None]
        tid = np.where(sub.track_id == c["track_a"][k], 0, 1)[None, :] + off
        big = Tracks(np.tile(sub.frame, D), tid.ravel(), np.tile(sub.cls, D), xy.reshape(-1, 2),
                     heading, np.tile(sub.size, (D, 1)), fps)
        mot = motion(big, opts.motion)
        ia = np.flatnonzero(big.track_id % 4 == 0)
        ib = np.flatnonzero(big.track_id % 4 == 1)
        # rows of a and b at the same frame, draw by draw (both sorted by draw, then frame)
        key_a = (big.track_id[ia] // 4) * (2**40) + big.frame[ia]
        key_b = (big.track_id[ib] // 4) * (2**40) + big.frame[ib]
        common, pa, pb = np.intersect1d(key_a, key_b, return_indices=True)
        a, b = ia[pa], ib[pb]
        inside = (big.frame[a] >= f0 + margin) & (big.frame[a] <= f1 - margin)
        a, b = a[inside], b[inside]
        x = ttc(big.xy[a], mot.heading[a], big.size[a], mot.vel[a], big.xy[b], mot.heading[b],
                big.size[b], mot.vel[b], opts.horizon_s)
        draw = big.track_id[a] // 4
        mins = np.full(D, np.inf)
        np.minimum.at(mins, draw, np.where(np.isfinite(x), x, np.inf))
        found = np.isfinite(mins)
        out["ttc_found_share"][k] = found.mean()
        out["ttc_found_share"][k] = found[1:].mean()
        if np.isfinite(c["min_ttc_s"][k]):
            _put(out, "min_ttc", k, _basic(c["min_ttc_s"][k], mins, q, iopts.spread[0]), iopts.details)
        if np.isfinite(c["ta_s"][k]):
            tas = _ta_draws(big, mot, D, f0 + margin, f1 - margin, opts)
            _put(out, "ta", k, _basic(c["ta_s"][k], tas, q, iopts.spread[1]), iopts.details)
        if np.isfinite(c["pet_s"][k]):
            pets = (_pet_draws_whole(big, mot, a, b, x, opts, D) if search is None
                    else _pet_draws(big, mot, c, k, search, opts.pet_s, D))
            out["pet_found_share"][k] = np.isfinite(pets[1:]).mean()
            _put(out, "pet", k, _basic(c["pet_s"][k], pets, q, iopts.spread[2]), iopts.details)
    return out


def _put(out: dict, name: str, k: int, got: tuple, details: bool) -> None:
    """Row k's interval ``got`` (``_basic``) into ``out``; with ``details`` also its centre
    and half widths (for calibrating ``spread``: benches/conflicts_noise.py)."""
    out[f"{name}_lo_s"][k], out[f"{name}_hi_s"][k] = got[:2]
    if details:
        for j, part in enumerate(("centre", "below", "above")):
            out.setdefault(f"{name}_{part}", np.full(len(out[f"{name}_lo_s"]), np.nan))[k] = got[2 + j]


def _basic(est: float, draws: np.ndarray, q, spread: float = 1.0) -> tuple[float, ...]:
    """The basic bootstrap interval of an indicator estimated as ``est``, from its values in
    the draws (D,) (NaN / inf: none in that draw; draw 0 the model world's, without error):
    [est - q_hi, est - q_lo] of the deviations d = draws[1:] - draws[0] (where draw 0 has
    none, draws[1:] - est), widened ``spread`` times about their median m:
    [est - m - spread (q_hi - m), est - m - spread (q_lo - m)], at least 0. Returns (lo, hi,
    est - m, spread's units below and above it: m - q_lo, q_hi - m); NaN where no draw has
    the indicator."""
    ref = draws[0] if np.isfinite(draws[0]) else est
    d = draws[1:][np.isfinite(draws[1:])] - ref
    if not len(d):
        return np.nan, np.nan, np.nan, np.nan, np.nan
    lo, m, hi = np.percentile(d, (q[0], 50.0, q[1]))
    centre = est - m
    return (max(0.0, centre - spread * (hi - m)), max(0.0, centre + spread * (m - lo)), centre,
            hi - m, m - lo)


def _ta_draws(big: Tracks, mot, D: int, f0: int, f1: int, opts) -> np.ndarray:
    """(D,) Time-to-Accident of each draw's pair (ids 4d, 4d + 1) over frames [f0, f1]."""
    ids = np.arange(D) * 4
    ta = time_to_accident(big, mot, onsets(big, mot, opts.evasive), ids, ids + 1,
                          np.full(D, f1), np.full(D, f0), opts.horizon_s)
    return ta["ta_s"]


def _pet_draws_whole(big: Tracks, mot, a: np.ndarray, b: np.ndarray, x: np.ndarray, opts,
                     D: int) -> np.ndarray:
    """(D,) PET of each draw, searched over the whole encounter as the table does: rows a, b
    at the same frames with TTC x (0: the footprints overlap there, PET 0, as the table's
    touching pairs). The draws are set apart in time (draw d's frames moved by d times the
    encounter's length and more than the PET window: frames are integers, so the positions
    and the frames' differences stay exactly those of the draw)."""
    span = int(big.frame.max() - big.frame.min()) + 1 + int(np.ceil((opts.pet_s + 1.0) * big.fps))
    step = max(1, int(round(opts.pet_options().sample_s * big.fps)))
    span = -(-span // step) * step  # PET's coarse search samples frames by step: keep the phase
    apart = big.take(slice(None))
    apart.frame = big.frame + (big.track_id // 4) * span  # rows keep their order (by draw)
    touch = x == 0
    pr = pet(apart, mot, opts.pet_options(), touching=np.c_[a[touch], b[touch]])
    out = np.full(D, np.nan)
    own = pr.track_a // 4 == pr.track_b // 4  # (pairs across draws cannot meet: too far apart)
    out[pr.track_a[own] // 4] = pr.pet[own]
    return out


def _pet_draws(big: Tracks, mot, c, k: int, search: int, window_s: float, D: int) -> np.ndarray:
    """(D,) PET of each draw, searched within ``search`` frames of the nominal pair of frames."""
    first_is_a = c["pet_first_track"][k] == c["track_a"][k]
    fx, fe = int(c["pet_exit_frame"][k]), int(c["pet_enter_frame"][k])
    fa_nom, fb_nom = (fx, fe) if first_is_a else (fe, fx)
    ra = np.flatnonzero((big.track_id % 4 == 0) & (np.abs(big.frame - fa_nom) <= search))
    rb = np.flatnonzero((big.track_id % 4 == 1) & (np.abs(big.frame - fb_nom) <= search))
    da, db = big.track_id[ra] // 4, big.track_id[rb] // 4
    # all pairs of rows of the same draw
    ia, ib = np.nonzero(da[:, None] == db[None, :])
    a, b = ra[ia], rb[ib]
    ok = np.abs(big.t[a] - big.t[b]) <= window_s
    a, b = a[ok], b[ok]
    hit = overlaps(big.xy[a], mot.heading[a], big.size[a], big.xy[b], mot.heading[b], big.size[b])
    best = closest_in_time(big, np.c_[a[hit], b[hit]])
    out = np.full(D, np.nan)
    if len(best):
        a, b = best[:, 0], best[:, 1]
        a_first = big.t[a] <= big.t[b]
        f1, f2 = np.where(a_first, a, b), np.where(a_first, b, a)
        t_exit, t_enter = refine(big, mot, f1, f2)
        out[big.track_id[a] // 4] = t_enter - t_exit
    return out
