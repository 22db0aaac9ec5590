"""Speed of `s2p conflicts` on a long recording: synthetic traffic through a junction, 1 hour
at 30 fps with about 50 road users in view at a time (cars on four approaches, a share of them
stopping at the stop line, pedestrians on the crossings, bicyclists), analysed for TTC, PET and
the conflict table. The traffic is drawn in numpy (no rendering): only the analysis is timed.

    PYTHONPATH=. .venv/bin/python benches/bench_conflicts.py [--hours 1] [--fps 30] [--in-view 50]
        [--seed 0] [--all-pairs] [--chunk 60] [--workers 2] [--profile N]

Prints the rows, the time of each step and the total, as CPU seconds of this process and its
worker processes (on a shared machine CPU time is the figure that does not depend on the other
users) and as wall-clock time, and the peak RSS of this process and of the largest worker;
docs/BENCHMARKS.md ("Traffic conflicts") records it.
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

from seg2pose.safety.conflicts import ConflictOptions, analyse, format_conflicts
from seg2pose.safety.tracks import CLASS_SIZES, Tracks

# class: (share of arrivals, speed m/s (low, high), route length m)
POPULATION = {"car": (0.6, (8.0, 14.0), 120.0), "pedestrian": (0.3, (1.1, 1.7), 30.0),
              "bicyclist": (0.1, (4.0, 6.0), 100.0)}


def junction_traffic(hours: float, fps: float, in_view: float, seed: int) -> Tracks:
    """Road users arriving as a Poisson process on the junction's approaches (cars and
    bicyclists on 8 lanes through the centre, pedestrians on 4 crossings), moving at a constant
    speed; 10 % of the cars wait 0-4 s at the stop line. Cut at ``hours``."""
    rng = np.random.default_rng(seed)
    shares = np.array([v[0] for v in POPULATION.values()])
    life = np.array([v[2] / np.mean(v[1]) for v in POPULATION.values()])
    rate = in_view / float((shares * life).sum())  # arrivals per second (Little's law)
    T = hours * 3600.0
    n = rng.poisson(rate * T)
    start = np.sort(rng.uniform(0, T, n))
    kind = rng.choice(len(POPULATION), n, p=shares)
    approach = rng.integers(0, 4, n)  # direction of travel: +x, +y, -x, -y
    waits = (kind == 0) & (rng.random(n) < 0.1)  # cars stopping at the stop line, own lane
    names = np.array(list(POPULATION), object)
    lo = np.array([v[1][0] for v in POPULATION.values()])[kind]
    hi = np.array([v[1][1] for v in POPULATION.values()])[kind]
    speed = rng.uniform(lo, hi)
    length = np.array([v[2] for v in POPULATION.values()])[kind]
    heading = approach * np.pi / 2
    # lanes: cars through -1.75 m, stopping cars -5.25 m, bicyclists -4 m (right of the
    # centre line); pedestrians on crossings 12 m either side of the centre, keeping right
    lane = np.select([kind == 1, kind == 2, waits], [rng.choice([-12.0, 12.0], n) - 0.5, -4.0 + 0 * speed,
                                                      -5.25 + 0 * speed], -1.75)
    wait = np.where(waits, rng.uniform(0, 4, n), 0.0)
    # one lane, one speed (no overtaking in this model), a gap of 1.5 s (6 s behind a car that
    # stops) after the one before
    for q in range(4):
        for group, gap in (((kind == 0) & ~waits, 1.5), ((kind == 0) & waits, 6.0),
                           (kind == 2, 2.0), (kind == 1, 1.0)):
            i = np.flatnonzero((approach == q) & group)
            if len(i):
                speed[i] = rng.uniform(lo[i[0]], hi[i[0]])
                k = gap * np.arange(len(i))
                start[i] = np.maximum.accumulate(start[i] - k) + k
    dur = length / speed + wait
    nf = np.maximum(2, (dur * fps).astype(np.int64))
    f0 = (start * fps).astype(np.int64)
    owner = np.repeat(np.arange(n), nf)
    k = np.arange(nf.sum()) - np.repeat(np.cumsum(nf) - nf, nf)
    t = k / fps
    w = wait[owner]
    half = length[owner] / 2 - 8.0  # the stop line, 8 m before the centre
    travel = speed[owner] * t
    stop_t = half / speed[owner]
    s = np.where(t < stop_t, travel, np.where(t < stop_t + w, half, speed[owner] * (t - w)))
    s = s - length[owner] / 2
    d = np.c_[np.cos(heading), np.sin(heading)][owner]
    nrm = np.c_[-d[:, 1], d[:, 0]]
    xy = d * s[:, None] + nrm * lane[owner][:, None]
    xy += rng.normal(0, 0.05, xy.shape)  # estimated tracks are not exact
    cls = names[kind][owner]
    size = np.array([CLASS_SIZES[c] for c in names])[kind][owner]
    keep = f0[owner] + k < T * fps
    return Tracks((f0[owner] + k)[keep], (owner + 1)[keep], cls[keep], xy[keep],
                  heading[owner][keep], size[keep], fps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--in-view", type=float, default=50.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--all-pairs", action="store_true")
    ap.add_argument("--chunk", type=float, default=60.0, help="seconds per chunk (0: whole recording)")
    ap.add_argument("--workers", type=int, default=2, help="processes for the time chunks")
    ap.add_argument("--profile", type=int, default=0, help="print the N functions of most CPU time (cProfile)")
    a = ap.parse_args()
    t0 = time.perf_counter()
    tr = junction_traffic(a.hours, a.fps, a.in_view, a.seed)
    per_frame = np.bincount(tr.frame - tr.frame.min())
    print(f"{len(tr):,} poses, {len(np.unique(tr.track_id)):,} road users, "
          f"{per_frame.mean():.1f} in view on average (max {per_frame.max()}); made in "
          f"{time.perf_counter() - t0:.1f} s")
    steps = {}

    def cpu():  # this process and its finished workers
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    last = [cpu(), None]

    def step(name):
        now = cpu()
        if last[1] is not None:
            steps[last[1]] = now - last[0]
        last[:] = [now, name]

    w1, t1 = time.perf_counter(), cpu()
    opts = ConflictOptions(all_pairs=a.all_pairs, chunk_s=a.chunk, workers=a.workers)
    if a.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        table = prof.runcall(analyse, tr, opts, progress=step)
    else:
        table = analyse(tr, opts, progress=step)
    step(None)
    total, wall = cpu() - t1, time.perf_counter() - w1
    text = format_conflicts(table, a.fps)
    t_fmt = cpu() - t1 - total
    print("CPU: " + "  ".join(f"{k} {v:.1f} s" for k, v in steps.items()))
    print(f"analysis {total:.1f} CPU s ({wall:.1f} s wall, {a.workers} workers) for {a.hours:g} h at {a.fps:g} fps: "
          f"{len(table):,} rows "
          f"({int(table.columns['conflict'].sum()):,} conflicts), {table.compared:,} pair-frames "
          f"compared for TTC; CSV text {t_fmt:.1f} s ({len(text) / 1e6:.1f} MB); peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB (largest worker "
          f"{resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6:.2f} GB)")
    if a.profile:
        pstats.Stats(prof).sort_stats("tottime").print_stats(a.profile)


if __name__ == "__main__":
    main()
