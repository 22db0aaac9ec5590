"""Kinematics for conflicts on noisy tracks: the local quadratic fits of ``seg2pose.safety.
kinematics`` (centred, width from each track's measured noise) against an RTS smoother with a
constant-acceleration model (Rauch, Tung and Striebel 1965; the same per-track noise, white
jerk of spectral density ``q``), on the hand-made cases of tests/seg2pose/safety/
test_literature.py with white position noise of 0.1-0.3 m added; and whether the 90 %
intervals (``--r90`` = 2.146 sigma, draws of white noise) hold the exact values.

    PYTHONPATH=. .venv/bin/python benches/conflicts_noise.py [--trials 20] [--draws 60] [--q 30 300]

Prints per case and noise level the median and 90th percentile of |min TTC - exact| and
|TA - exact| for each smoother, and the intervals' coverage (local fits).
"""

from __future__ import annotations

import argparse

import numpy as np

from seg2pose.safety.conflicts import ConflictOptions, analyse
from seg2pose.safety.gaps import fill_gaps
from seg2pose.safety.intervals import IntervalOptions, conflict_intervals
from seg2pose.safety.kinematics import Motion, fill_heading, noise_sigma, segments
from tests.seg2pose.safety import test_literature as L

OPTS = ConflictOptions(workers=1)
U = 1 - np.sqrt(0.6)
CASES = {  # name: (tracks, exact min TTC, exact TA)
    "braking follower": (L.braking_follower, (4 - 5 * U + 2.5 * U * U) / (5 - 5 * U), 0.8),
    "pedestrian ahead": (L.pedestrian_ahead, None, 1.29),
}


def rts(tracks, q: float) -> Motion:
    """Motion from an RTS smoother with a constant-acceleration model per axis and track:
    state (p, v, a), white jerk of spectral density q (m^2/s^5), measurement noise the track's
    (``kinematics.noise_sigma``, at least 1 mm)."""
    st, en = segments(tracks)
    sigma = np.maximum(noise_sigma(tracks, st, en), 1e-3)
    dt = 1.0 / tracks.fps
    F = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
    Q = q * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6], [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                      [dt ** 3 / 6, dt ** 2 / 2, dt]])
    H = np.array([[1.0, 0, 0]])
    vel = np.zeros((len(tracks), 2))
    acc = np.zeros((len(tracks), 2))
    for s in np.unique(st):
        rows = np.arange(s, en[s] + 1)
        R = sigma[s] ** 2
        for ax in range(2):
            z = tracks.xy[rows, ax]
            n = len(z)
            xf, Pf, xp, Pp = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
            x = np.array([z[0], (z[min(1, n - 1)] - z[0]) / dt if n > 1 else 0.0, 0.0])
            P = np.diag([R, 100.0, 100.0])
            for k in range(n):
                if k:
                    x, P = F @ x, F @ P @ F.T + Q
                xp[k], Pp[k] = x, P
                S = (H @ P @ H.T)[0, 0] + R
                K = (P @ H.T)[:, 0] / S
                x = x + K * (z[k] - x[0])
                P = P - np.outer(K, H @ P)
                xf[k], Pf[k] = x, P
            xs = xf.copy()
            for k in range(n - 2, -1, -1):
                C = Pf[k] @ F.T @ np.linalg.inv(Pp[k + 1])
                xs[k] = xf[k] + C @ (xs[k + 1] - xp[k + 1])
            vel[rows, ax], acc[rows, ax] = xs[:, 1], xs[:, 2]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    heading = fill_heading(tracks, vel, speed, 0.5)
    d = np.where((speed >= 0.5)[:, None], vel / np.maximum(speed, 1e-12)[:, None],
                 np.c_[np.cos(heading), np.sin(heading)])
    along = (acc * d).sum(axis=1)
    lateral = acc[:, 1] * d[:, 0] - acc[:, 0] * d[:, 1]
    n0 = np.zeros(len(tracks), np.int64)
    return Motion(vel, speed, acc, along, lateral, heading, sigma, n0 + 5, n0 + 5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--draws", type=int, default=60)
    ap.add_argument("--q", type=float, nargs="+", default=[30.0, 300.0])
    ap.add_argument("--noise", type=float, nargs="+", default=[0.1, 0.2, 0.3])
    a = ap.parse_args()
    rng = np.random.default_rng(0)

    def q(x, p):
        x = np.asarray(x, float)
        x = x[np.isfinite(x)]
        return float(np.percentile(x, p)) if len(x) else float("nan")

    for name, (make, ttc_exact, ta_exact) in CASES.items():
        base = make()
        for s in a.noise:
            err: dict[str, tuple[list, list]] = {"local": ([], [])} | {f"rts q={v:g}": ([], []) for v in a.q}
            cover_ttc, cover_ta, found_ta = [], [], 0
            for _ in range(a.trials):
                noisy = base.with_xy(base.xy + rng.normal(0, s, base.xy.shape))
                t = analyse(noisy, OPTS)
                c = t.columns
                if ttc_exact is not None:
                    err["local"][0].append(abs(c["min_ttc_s"][0] - ttc_exact))
                err["local"][1].append(abs(c["ta_s"][0] - ta_exact))
                found_ta += int(np.isfinite(c["ta_s"][0]))
                ft = t.tracks
                assert ft is not None
                iv = conflict_intervals(ft, t, OPTS, IntervalOptions(draws=a.draws, corr_s=1.0 / base.fps),
                                        r90=np.full(len(ft), s * 2.146))
                if ttc_exact is not None and np.isfinite(iv["min_ttc_lo_s"][0]):
                    cover_ttc.append(iv["min_ttc_lo_s"][0] <= ttc_exact <= iv["min_ttc_hi_s"][0])
                if np.isfinite(iv["ta_lo_s"][0]):
                    cover_ta.append(iv["ta_lo_s"][0] <= ta_exact <= iv["ta_hi_s"][0])
                filled, _, _ = fill_gaps(noisy, OPTS.max_gap_s)
                for v in a.q:
                    tr = analyse(filled, OPTS, mot=rts(filled, v)).columns
                    if ttc_exact is not None:
                        err[f"rts q={v:g}"][0].append(abs(tr["min_ttc_s"][0] - ttc_exact))
                    err[f"rts q={v:g}"][1].append(abs(tr["ta_s"][0] - ta_exact))
            print(f"{name}, noise {s:g} m ({a.trials} trials):")
            for k, (e_ttc, e_ta) in err.items():
                print(f"  {k:12s} |min TTC err| median {q(e_ttc, 50):.3f} p90 {q(e_ttc, 90):.3f} s;"
                      f" |TA err| median {q(e_ta, 50):.3f} p90 {q(e_ta, 90):.3f} s"
                      f" (TA found {np.isfinite(e_ta).sum()})")
            ttc_cov = np.mean(cover_ttc) if cover_ttc else float("nan")
            print(f"  local fits' 90 % intervals: min TTC coverage {ttc_cov:.2f}"
                  f" (n={len(cover_ttc)}), TA coverage {np.mean(cover_ta) if cover_ta else float('nan'):.2f}"
                  f" (n={len(cover_ta)}); TA found {found_ta}/{a.trials}")


if __name__ == "__main__":
    main()
