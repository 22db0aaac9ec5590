"""Kill s2p commands at random moments, many times, and count what their outputs are left as.

Every writing command on small inputs (tests/kill_cases.py, killed by tests/kill_harness.py):
``s2p run``, ``synth``,
``convert-masks``, ``import-utocs``, ``export`` (issue 10) and ``masks-from-video``,
``import-detections``, ``track``, ``new-scene``, ``import-tacal``, ``annotate export`` (gt +
MCAP + layout + CSV as one set), ``import-mcap --force`` (into an existing scene folder),
``annotate import-tanalyst``, ``associate``, ``batch --serial`` and ``batch`` on a local Ray of
its own (``batch-ray``: the driver killed; about 35 s a run, most of it Ray's start) (issues 23
and 24), and ``train`` (killed, then resumed: the re-run must end with the uninterrupted run's
models byte for byte; a model marked incomplete counts as absent, since readers refuse it).
Put complete old outputs in place, start the command (with --force where it replaces them),
SIGKILL it after a random share (0.15-1.05, ``--share``) of its usual duration, and classify
the outputs: absent, the complete old ones, the complete new ones, or mixed (anything else,
also a set of which some outputs are old and some new: counted as the outputs are the moment
after the kill; "finished" says how many of those the next writer's first step,
``finish_commits``, made the new set). ``batch`` is then run again without --force, as a user
would after a crash: "between" counts kills that left some steps done (each output whole) and
a re-run that fails or ends anywhere but at the uninterrupted run's outputs is mixed. The
promise is 0 mixed. Then one full run checks that the dead writers' leftovers are removed.

Also (issue 38, tests/kill_cases_more.py) ``review -o``, ``screenshot`` (its headless viewers:
none may outlive a kill, and no /tmp/s2p-viewer-state-* folder of theirs may stay),
``calibrate-errors``, ``conflicts`` and ``calibrate-camera --points``. And kills timed at each
commit step (``--steps`` per step, ``Case.kill_forks``: at the first commit of each kind of
output the command, or the Ray worker that commits, forks children that die at the step,
exactly or after a sub-delay; the journal's "appended" step killed in the command itself).

    python benches/bench_faults.py [--kills 100] [--steps 10] [--seed 0] [--only run,synth] [--share 0.15,1.05]
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
from kill_cases import build_cases, build_training_cases, build_writer_cases  # noqa: E402
from kill_cases_more import build_more_cases, viewer_states  # noqa: E402

MORE = ["review-o", "screenshot", "calibrate-errors", "conflicts", "calibrate-camera"]


def _ray_sessions(root: Path = Path(tempfile.gettempdir()) / "ray") -> tuple[int, int]:
    """Ray's session folders on this machine and their bytes."""
    if not root.is_dir():
        return 0, 0
    dirs = [d for d in root.iterdir() if d.name.startswith("session_2") and d.is_dir()]
    size = sum(f.stat().st_size for d in dirs for f in d.rglob("*") if f.is_file() and not f.is_symlink())
    return len(dirs), size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=100, help="kills per command")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="", help="comma-separated commands (default: all)")
    ap.add_argument("--steps", type=int, default=10, help="kills timed at each commit step: "
                    "at most this many per step (0: none)")
    ap.add_argument("--share", default="0.15,1.05", help="kill after a random share in this "
                    "range of the command's duration (e.g. 0.3,0.8: fewer kills after the end)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        only = args.only.split(",") if args.only else None
        first = ["run", "synth", "convert-masks", "import-utocs", "export"]
        cases = []
        if only is None or set(only) & set(first):
            cases += build_cases(Path(d) / "first", frames=20)
        if only is None or set(only) - set(first) - set(MORE) - {"train"}:
            cases += build_writer_cases(Path(d) / "writers")
        if only is None or set(only) & set(MORE):
            cases += build_more_cases(Path(d) / "more")
        if only is None or "train" in only:
            cases += build_training_cases(Path(d) / "training")
        if only:
            cases = [c for c in cases if c.name in only]
        rng = np.random.default_rng(args.seed)
        share = tuple(float(x) for x in args.share.split(","))
        print(f"{'command':>17} {'kills':>6} {'timed':>6} {'absent':>7} {'old':>5} {'new':>5} {'between':>8} "
              f"{'mixed':>6} {'finished':>9} {'leftovers':>10} {'s/run':>6}", flush=True)
        total_mixed = total_left = total_stray = 0
        for c in cases:
            sessions = _ray_sessions()
            c.run_fully()
            t = time.perf_counter()
            for k in range(1, args.kills + 1):
                c.kill_once(rng, share)
                if k % 50 == 0 and k < args.kills:
                    print(f"  {c.name}: {k} kills so far: {c.counts}", flush=True)
            timed = 0
            if args.steps:
                # killed at each commit step, --steps times a step of each commit (judged after
                # the next writer's first step)
                from seg2pose.io.kill_points import DELAYS

                kinds = c.kill_forks(args.steps)
                if c.name == "import-tanalyst":  # the journal's append: no commit to fork at
                    kinds["appended"] = [c.kill_at("appended", 1, x) for x in [0.0, *DELAYS][:args.steps]]
                timed = sum(map(len, kinds.values()))
                print(f"    timed: {({s: len(k) for s, k in kinds.items()})}", flush=True)
            c.run_fully()  # the next writer takes over and cleans up
            left = len(c.leftovers()) + len(viewer_states(c))
            n = c.counts
            total_mixed += n["mixed"]
            total_left += left
            total_stray += c.stray
            print(f"{c.name:>17} {args.kills:>6} {timed:>6} {n['absent']:>7} {n['old']:>5} {n['new']:>5} "
                  f"{n['between']:>8} {n['mixed']:>6} {n['finished']:>9} {left:>10} {c.seconds:>6.2f}   "
                  f"({time.perf_counter() - t:.0f} s)", flush=True)
            if c.name == "screenshot":
                print(f"    {c.stray} viewer processes still running 120 s after their kill; "
                      f"{len(viewer_states(c))} viewer state folders left", flush=True)
            elif c.tree:  # Ray: what the killed drivers' clusters left running or on disk
                print(f"    {c.stray} processes of the killed commands still running 120 s after "
                      f"their kill; {_ray_sessions()[0] - sessions[0]} Ray session folders "
                      f"added ({(_ray_sessions()[1] - sessions[1]) / 1e6:.1f} MB)", flush=True)
            for states, beside in c.mixed:
                print(f"    mixed: outputs {states}, beside them {beside}", flush=True)
        print(f"mixed or partial outputs: {total_mixed}; left over after the next run: {total_left}; "
              f"processes outliving their kill: {total_stray}")
        sys.exit(1 if total_mixed or total_left or total_stray else 0)


if __name__ == "__main__":
    main()
