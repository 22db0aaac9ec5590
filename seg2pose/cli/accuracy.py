"""The accuracy benchmark's driver (``s2p bench-accuracy``): synth -> heights -> train ->
paper-table on several scene seeds, then ``seg2pose.eval.accuracy``'s summary.

Each step is the ``s2p`` command a user would type (printed as it runs), so the benchmark
measures exactly what the README tells users to do. Steps whose outputs exist are skipped:
an interrupted benchmark resumes (training itself resumes from its checkpoints).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from seg2pose.core.errors import S2PError
from seg2pose.eval.accuracy import SMOOTHED, SeedResult, read_table, smoothed_results, summary
from seg2pose.io.atomic import atomic_write_text, copy_tree
from seg2pose.io.nofollow import fdopen_nofollow
from seg2pose.training.config import ROUGH_STAGE

# training variants: name -> the `s2p train` options (the CPU protocol of docs/RESULTS.md)
VARIANTS = {
    "s2pn": ["--protocol", "quick"],
    "s2pn-long": ["--protocol", "long"],   # = quick --epochs 60 --rough-every 4
    "zero": ["--protocol", "quick", "--zero-annotation", "--rough", "400"],
    "zero-random": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--rough-random"],
    "zero-track": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--self-train", "track"],
    "zero-fused": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--self-train", "fused"],
    "zero-views": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--self-train", "views"],
    # the parts together (issue 25's ladder: rough models, + randomised, + track, + multi-view)
    "zero-random-track": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--rough-random",
                          "--self-train", "track"],
    "zero-random-views": ["--protocol", "quick", "--zero-annotation", "--rough", "400", "--rough-random",
                          "--self-train", "views"],
}
# self-training variants start from another variant's rough-only models: when that variant's
# folder is finished, its models are copied in as the first stage instead of retrained
# (``self_training.check_rough_stage`` refuses them if the protocols differ)
ROUGH_STAGE_OF = {"zero-track": "zero", "zero-fused": "zero", "zero-views": "zero",
                  "zero-random-track": "zero-random", "zero-random-views": "zero-random"}

def s2p_command(*args: str) -> list[str]:
    """argv running ``s2p ARGS`` with this interpreter (and so this checkout's code)."""
    return [sys.executable, "-c", "from seg2pose.cli import main; main()", *map(str, args)]


def run_seed(root: Path, seed: int, preset: str = "bench", variants=("s2pn", "zero"),
             threads: int = 2, train_args: tuple[str, ...] = (), log=print,
             smooth: int = 0) -> SeedResult:
    """The whole protocol on one scene seed; returns its errors (with ``smooth`` > 0 also
    every run smoothed along the tracks: rows "baseline+smooth", "<variant>+smooth")."""
    scene = Path(root) / f"{preset}-seed{seed}"
    res = SeedResult(seed)

    def step(argv: list, what: str) -> float:
        """Run ``s2p ARGV``; its output goes to ROOT/logs/seed<N>-<what>.log."""
        argv = [str(a) for a in argv]
        logs = Path(root) / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        out = logs / f"seed{seed}-{what}.log"
        log(f"$ s2p {' '.join(argv)}    (output: {out})")
        t = time.perf_counter()
        with fdopen_nofollow(out, "w") as f:  # a log planted as a link is refused, not truncated
            r = subprocess.run(s2p_command(*argv), stdout=f, stderr=subprocess.STDOUT, text=True)
        if r.returncode:
            raise S2PError(f"{what} failed for seed {seed}; its output: {out}")
        return time.perf_counter() - t

    if not (scene / "scene.json").exists():
        step(["synth", "-o", scene, "--preset", preset, "--seed", seed, "--no-progress"], "synth")
        step(["heights", scene], "heights")
    for v in variants:
        models = scene / f"models-{v}"
        table = scene / f"table-{v}"
        meta = models / "bench.json"
        base = scene / f"models-{ROUGH_STAGE_OF.get(v)}"
        if not meta.exists() and v in ROUGH_STAGE_OF and (base / "bench.json").exists() \
                and not (models / ROUGH_STAGE).exists():
            log(f"copying {base} to {models / ROUGH_STAGE} (the rough-only stage)")
            copy_tree(base, models / ROUGH_STAGE, ignore=shutil.ignore_patterns("bench.json"))
        if not meta.exists():
            secs = step(["train", scene, *VARIANTS[v], *train_args, "--threads", threads,
                         "-o", models], f"train-{v}")
            atomic_write_text(meta, json.dumps({"train_s": secs, "options": [*VARIANTS[v], *train_args]}))
        res.train_s[v] = json.loads(meta.read_text())["train_s"]
        if not (table / "results.json").exists():
            step(["paper-table", scene, "--models", models, "-o", table, "--force"], f"paper-table-{v}")
        read_table(table / "results.json", v, res)
        if smooth:
            read_table(smoothed_results(scene, table, smooth), v, res, SMOOTHED)
    return res


def run_benchmark(root: str | Path, seeds: list[int], preset: str = "bench",
                  variants=("s2pn", "zero"), threads: int = 2, train_args: tuple[str, ...] = (),
                  log=print, smooth: int = 0) -> tuple[list[SeedResult], str]:
    """``run_seed`` for every seed, then ``summary``; also writes ROOT/accuracy.json."""
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise S2PError(f"unknown variant(s) {', '.join(unknown)}; use {', '.join(VARIANTS)}")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    results = [run_seed(root, s, preset, variants, threads, train_args, log, smooth) for s in seeds]
    text = summary(results, variants)
    atomic_write_text(root / "accuracy.json", json.dumps(
        {"preset": preset, "variants": {v: VARIANTS[v] + list(train_args) for v in variants},
         "smooth_frames": smooth,
         "seeds": [vars(r) for r in results]}, indent=1) + "\n")
    return results, text
