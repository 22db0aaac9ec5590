"""Kill s2p commands at random moments, many times, and count what their outputs are left as.

For each of ``s2p run``, ``synth``, ``convert-masks``, ``import-utocs`` and ``export`` (small
inputs, tests/kill_harness.py): put a complete old output in place, start the command with
--force, SIGKILL it after a random share (0.15-1.05) of its usual duration, and classify the
output: absent, the complete old one, the complete new one, or mixed (anything else). The
promise is 0 mixed. Then one full run checks that the dead writers' leftovers are removed.

    python benches/bench_faults.py [--kills 200] [--seed 0] [--only run,synth]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # this checkout's s2p, also in the killed commands
from kill_harness import build_cases  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=200, help="kills per command")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="", help="comma-separated commands (default: all five)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        cases = build_cases(Path(d), frames=20)
        if args.only:
            cases = [c for c in cases if c.name in args.only.split(",")]
        rng = np.random.default_rng(args.seed)
        print(f"{'command':>14} {'kills':>6} {'absent':>7} {'old':>5} {'new':>5} {'mixed':>6} "
              f"{'leftovers':>10} {'s/run':>6}", flush=True)
        total_mixed = 0
        for c in cases:
            c.run_fully()
            t = time.perf_counter()
            for k in range(1, args.kills + 1):
                c.kill_once(rng)
                if k % 50 == 0 and k < args.kills:
                    print(f"  {c.name}: {k} kills so far: {c.counts}", flush=True)
            c.run_fully()  # the next writer takes over and cleans up
            left = len(c.leftovers())
            n = c.counts
            total_mixed += n["mixed"]
            print(f"{c.name:>14} {args.kills:>6} {n['absent']:>7} {n['old']:>5} {n['new']:>5} "
                  f"{n['mixed']:>6} {left:>10} {c.seconds:>6.2f}   "
                  f"({time.perf_counter() - t:.0f} s)", flush=True)
        print(f"mixed or partial outputs: {total_mixed}")
        sys.exit(1 if total_mixed else 0)


if __name__ == "__main__":
    main()
