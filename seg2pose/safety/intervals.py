"""Error intervals of the indicators: each conflict recomputed on ``draws`` versions of its two
tracks with the positions moved within their uncertainty.

A pose with ``r90_m`` = R has its true position within R metres with 90 % probability; as an
isotropic 2D Gaussian that is sigma = R / sqrt(2 ln 10) = R / 2.146 per axis. Pose errors of
one road user are not independent from frame to frame (the same mask errors persist), so each
draw moves a track by an AR(1) process with correlation time ``corr_s`` seconds (per axis:
e_k = rho e_(k-1) + sqrt(1 - rho^2) z_k, rho = exp(-dt / corr_s)), scaled by each row's sigma.
Velocities are re-estimated from the moved positions, so the interval of TTC carries the
velocity error too. The interval is the basic bootstrap interval of the central ``level`` of
the draws (``_basic``: the draws' 5th and 95th percentiles reflected around the estimate, so
that the bias of a minimum over noisy frames is corrected, not doubled) for min TTC and TA;
PET's is the draws' 5th to 95th percentile (PET is a fact of the positions, not of a
velocity: no such bias); ``*_found_share`` says in how many draws the indicator exists at all (a draw with no
collision course has no TTC).

Only the encounter's own frames (with a margin for the velocity window) are redrawn, so this
costs little per conflict. PET is searched in each draw as the table searches it, over the
whole encounter (``pet.pet``; the draws set apart in time so that they never meet): where
two road users share a path, the least PET may lie elsewhere in a draw than in the tracks
(searching only near the nominal pair of frames, ``pet_search_s``, as before, made the
intervals too narrow).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from seg2pose.safety.evasive import onsets, time_to_accident
from seg2pose.safety.footprints import overlaps
from seg2pose.safety.kinematics import motion
from seg2pose.safety.pet import closest_in_time, pet, refine
from seg2pose.safety.tracks import Tracks
from seg2pose.safety.ttc import ttc

SIGMA_PER_R90 = 1.0 / np.sqrt(2.0 * np.log(10.0))
SIGMA_PER_HEADING90 = 1.0 / 1.6449  # |N(0, sigma)| is below 1.645 sigma 90 % of the time


@dataclass(frozen=True)
class IntervalOptions:
    """draws: samples per conflict; corr_s: correlation time of pose errors, seconds; level:
    the interval's coverage (``corr_s`` 3 s covered best on the tuning scene, seed 201: 0.3,
    1, 3, 10 s tried); pet_search_s: None (the default): PET searched over the whole
    encounter, as in the table; a number: only this close to the nominal frames (before);
    seed: of the draws (the same seed gives the same intervals)."""

    draws: int = 200
    corr_s: float = 3.0
    level: float = 0.9
    pet_search_s: float | None = None
    seed: int = 0


def ar1_noise(n: int, draws: int, rho: float, rng: np.random.Generator) -> np.ndarray:
    """(draws, n, 2) stationary AR(1) noise of unit variance."""
    z = rng.standard_normal((draws, n, 2))
    z[:, 0] /= np.sqrt(max(1.0 - rho * rho, 1e-12))  # start in the stationary distribution
    return lfilter([np.sqrt(1.0 - rho * rho)], [1.0, -rho], z, axis=1)


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
    """INTERVAL_COLUMNS for each row of ``table`` (a ConflictTable of ``tracks``), (K,) arrays.
    ``r90``: (N,) metres per row of ``tracks`` (default ``tracks.r90``); rows with NaN get no
    noise. ``heading90``: (N,) radians per row, the heading error 90 % of the poses stay
    within (None: headings not perturbed; drawn after the positions, with the same
    correlation, so the position draws do not change). ``opts``: the ConflictOptions the
    table was made with."""
    r90 = tracks.r90 if r90 is None else r90
    K = len(table)
    out = {k: np.full(K, np.nan) for k in ("min_ttc_lo_s", "min_ttc_hi_s", "pet_lo_s", "pet_hi_s",
                                           "ta_lo_s", "ta_hi_s", "ttc_found_share", "pet_found_share")}
    if r90 is None:
        return out
    c = table.columns
    fps = tracks.fps
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
        sig = np.nan_to_num(r90[rows] * SIGMA_PER_R90)  # rows: a's then b's, as sub sorts them
        D = iopts.draws
        # one Tracks with D copies of the pair, copy d's ids offset so they stay apart
        noise = np.concatenate([ar1_noise(int((sub.track_id == tr).sum()), D, rho, rng)
                                for tr in np.unique(sub.track_id)], axis=1)
        xy = sub.xy[None] + noise * sig[None, :, None]
        heading = np.tile(sub.heading, D)
        if heading90 is not None:
            hn = np.concatenate([ar1_noise(int((sub.track_id == tr).sum()), D, rho, rng)[..., 0]
                                 for tr in np.unique(sub.track_id)], axis=1)
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
        if found.any() and np.isfinite(c["min_ttc_s"][k]):
            out["min_ttc_lo_s"][k], out["min_ttc_hi_s"][k] = _basic(c["min_ttc_s"][k], mins[found], q)
        if np.isfinite(c["ta_s"][k]):
            tas = _ta_draws(big, mot, D, f0 + margin, f1 - margin, opts)
            ok = np.isfinite(tas)
            if ok.any():
                out["ta_lo_s"][k], out["ta_hi_s"][k] = _basic(c["ta_s"][k], tas[ok], q)
        if np.isfinite(c["pet_s"][k]):
            pets = (_pet_draws_whole(big, mot, a, b, x, opts, D) if search is None
                    else _pet_draws(big, mot, c, k, search, opts.pet_s, D))
            ok = np.isfinite(pets)
            out["pet_found_share"][k] = ok.mean()
            if ok.any():
                out["pet_lo_s"][k], out["pet_hi_s"][k] = np.percentile(pets[ok], q)
    return out


def _basic(est: float, draws: np.ndarray, q) -> tuple[float, float]:
    """The basic bootstrap interval of an indicator estimated as ``est`` whose draws (with
    the poses moved once more) are ``draws``: [2 est - q_hi, 2 est - q_lo], at least 0. A
    minimum over noisy frames is biased low, and the draws are biased low again by about as
    much: the percentile interval of the draws would sit on the wrong side of the truth."""
    lo, hi = np.percentile(draws, q)
    return max(0.0, 2.0 * est - hi), max(0.0, 2.0 * est - lo)


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
