"""s2p batch: a study of small synthetic scenes serially in-process vs on a local Ray with 2
workers (issue 16; goal: wall-time ratio >= 1.7 on this 2-core machine), the overhead per Ray
task, and each step's speed per core (frames per CPU-second) for docs/SCALE.md.

    OMP_NUM_THREADS=1 .venv/bin/python benches/bench_batch.py [--scenes 8] [--frames 40]

Steps: run --baseline, eval, export (MCAP). The machine may be shared: the driver's CPU time
and the load average are printed beside the wall times.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def noop_run(scene_dir, opts, force):  # the cost of a task that does nothing
    return {}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=8)
    ap.add_argument("--frames", type=int, default=40, help="frames per split (3 splits a scene)")
    args = ap.parse_args()

    import ray

    from seg2pose.batch import BATCH_DIR, BatchOptions, Step, run_study
    from seg2pose.cli.batch import STEPS
    from seg2pose.synth.generate import generate_scene

    steps = [STEPS["run"], STEPS["eval"], STEPS["export"]]
    opts = BatchOptions()
    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        for i in range(args.scenes):
            generate_scene(root / f"s{i:02d}", frames=args.frames, seed=i, progress=False, workers=1)

        def clear():
            for s in root.iterdir():
                shutil.rmtree(s / BATCH_DIR, ignore_errors=True)

        quiet = dict(progress=False, log=lambda s: None)
        c0, t0 = time.process_time(), time.perf_counter()
        ser = run_study(root, steps, opts, use_ray=False, **quiet)
        t_ser, c_ser = time.perf_counter() - t0, time.process_time() - c0
        assert ser.n_failed == 0
        frames = sum(r["info"]["frames"] for r in ser.results["run"])
        print(f"{args.scenes} scenes, {frames} frames x 5 cameras; load average {os.getloadavg()[0]:.1f}")
        print(f"serial: {t_ser:.2f} s wall, {c_ser:.2f} s CPU")
        for name, rs in ser.results.items():  # per-core speed: one step on one core
            sec = sum(r["seconds"] for r in rs)
            print(f"  {name:<7} {sec:6.2f} s  {frames / sec:8.1f} frames/s per core")

        t0 = time.perf_counter()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        t_init = time.perf_counter() - t0
        try:
            noop = Step("noop", lambda s, o: [], lambda s, o: [], noop_run)
            run_study(root, [noop], opts, **quiet)  # starts the two workers
            clear()
            t0 = time.perf_counter()
            run_study(root, [noop], opts, **quiet)
            t_noop = time.perf_counter() - t0
            clear()
            c0, t0 = time.process_time(), time.perf_counter()
            par = run_study(root, steps, opts, **quiet)
            t_par, c_par = time.perf_counter() - t0, time.process_time() - c0
            assert par.n_failed == 0
            task_sec = sum(r["seconds"] for rs in par.results.values() for r in rs)
        finally:
            ray.shutdown()
        n_tasks = args.scenes * len(steps)
        print(f"ray (2 workers): {t_par:.2f} s wall (+ {t_init:.1f} s ray.init, once), "
              f"driver CPU {c_par:.2f} s, tasks' own time {task_sec:.2f} s over 2 workers; "
              f"load average {os.getloadavg()[0]:.1f}")
        print(f"wall-time ratio serial / ray: {t_ser / t_par:.2f} (goal >= 1.7 on 2 idle cores)")
        print(f"overhead per task: {t_noop / args.scenes * 1e3:.1f} ms (empty task, 2 workers); "
              f"{(t_par - task_sec / 2) / n_tasks * 1e3:.1f} ms per task of this study "
              f"(wall minus the tasks' own time / 2)")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
