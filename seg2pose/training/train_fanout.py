"""The training protocol's independent runs as tasks (``s2p train --parallel/--address``):
camera x class x run, on Ray (``seg2pose.core.ray.ray_map``) or any ``map``, with the
checkpoints of the serial protocol.

Why the result is the same: a camera group's examples come from its own random stream
(``training_data.model_jobs``), so the groups' examples are built as one task per group, in
the serial order within the group. A run depends only on its seed (``seed + run``: torch and
the batch draws are seeded at its start), so each (model, run) trains alone, into
``<model>.run<k>.safetensors``. The serial protocol keeps the first epoch with the lowest
validation loss over runs 1..N, i.e. the run with the lowest best loss, the earliest on a tie,
and that run's checkpoint carries the same weights and metadata (seed, run, epoch, losses) as
the serial one: it is renamed to the model's name and the other runs are removed.

Resuming: a run interrupted mid-way continues from its own resume state; a finished run file
of the same protocol and scene is not trained again (run-time settings such as the threads
may differ).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from seg2pose.core.say import say
from seg2pose.io.atomic import rename
from seg2pose.method.checkpoint import Checkpoint
from seg2pose.training.config import TrainConfig, same_protocol


def run_path(path: Path, run: int) -> Path:
    """``MODELS/c0__car.safetensors`` -> ``MODELS/c0__car.run2.safetensors`` for run 1 (0-based)."""
    return path.with_name(f"{path.stem}.run{run + 1}{path.suffix}")


def _finished_run(p: Path, cfg: TrainConfig, scene_fp: str, force: bool) -> dict | None:
    """The best info of a finished run file of this protocol and scene, else None."""
    if force or not p.exists() or p.with_name(p.name + ".state.pt").exists():
        return None
    try:
        ck = Checkpoint.load(p)
    except Exception:  # noqa: BLE001 - a damaged run file is trained again
        return None
    info = ck.info
    if info.get("complete") and same_protocol(info.get("train_config"), cfg) and ck.scene_fingerprint == scene_fp:
        return info
    return None


def _move(src: Path, dst: Path) -> None:
    rename(src.with_suffix(".json"), dst.with_suffix(".json"))
    rename(src, dst)  # the weights last: a complete .safetensors marks a finished model


def fan_out(mapper: Callable, groups: list, group_jobs: Callable, train_job: Callable,
            finish_job: Callable, cfg: TrainConfig, scene_fp: str, force: bool = False) -> None:
    """Train every model of ``groups`` with ``mapper(fn, items)`` (e.g. ``ray_map``):
    ``group_jobs(group) -> [ModelJob]`` (examples), ``train_job(job, runs, path) -> best
    info`` (one run into ``path``), ``finish_job(job)`` (after the best run is in place)."""
    jobs = [j for js in mapper(group_jobs, groups) for j in js]
    units = [(j, r) for j in jobs for r in range(cfg.runs)]

    def one_run(unit) -> dict:
        job, r = unit
        p = run_path(job.path, r) if cfg.runs > 1 else job.path
        done = _finished_run(p, cfg, scene_fp, force) if cfg.runs > 1 else None
        return done if done is not None else train_job(job, [r], p)

    bests = list(mapper(one_run, units))
    for k, job in enumerate(jobs):
        losses = [float(b["val_loss"]) for b in bests[k * cfg.runs:(k + 1) * cfg.runs]]
        r = min(range(cfg.runs), key=lambda i: (losses[i], i))  # the serial "<": earliest on a tie
        if cfg.runs > 1:
            _move(run_path(job.path, r), job.path)
            for q in range(cfg.runs):
                if q != r:
                    for f in (run_path(job.path, q), run_path(job.path, q).with_suffix(".json")):
                        f.unlink(missing_ok=True)
            say(f"{job.path.stem}: best of {cfg.runs} runs is run {r + 1} "
                f"(val loss {losses[r]:.4f})")
        finish_job(job)

