"""The annotation-efficiency curve (issue 41): mean error against the truth on the test split
after K keyframes, the keyframes chosen by the app's queue (annotate.suggest) or uniformly, and
Seg2PoseNet fine-tuned from a start (``s2p train --from``: the shipped demo models, a
zero-annotation run's models, or from scratch).

    s2p synth -o /tmp/ft/wS --preset wide --video --look rich --frames 100 --seed S
    nice -n 10 .venv/bin/python benches/annotation_curve.py /tmp/ft/wS --out /tmp/ft/curve \\
        --start shipped --chooser app --chooser uniform -k 0 -k 10 -k 25

Per scene (camera c1 only, ``-c mono-1``; every step through the library, timed):

1. prep (once, marked done): ``masks-from-video --camera c1`` (the truth's masks are not used:
   background subtraction, tracker, size classes), ``heights --rough 2000 --camera c1`` (no
   annotation needed); a copy of the scene without its truth is the annotator's scene (WORK);
2. the baseline (test split) and every start's run on all frames (its K = 0 row, and the app's
   queue outside the test split) on WORK, scored on the test split against the truth
   (``evaluate_run --match nearest``: the tracker's ids are not the truth's);
3. per chooser and K: a fresh annotation project on WORK; the scripted annotator takes road
   users from the chooser -- ``app``: ``annotate.suggest.annotation_queue`` on the start model's
   run outside the test split (the shipped start's for scratch, which has nothing to say);
   ``uniform``: the same tracks in a random order (seeded) -- and in
   each of the candidate's frames clicks the truth road user whose projected box centre is
   nearest the mask's centre (a keyframe at its true x, y and heading, through the engine's
   API), until K keyframes; ``export_gt`` writes gt/poses.csv (keyframe / interpolated rows);
4. ``fine_tune_scene`` from the start (CPU time of the process measured), a test-split run and
   its score. The actions a person would take: one per track made, two per keyframe (go to
   the suggested frame, click).

Writes OUT/<scene>/curve.jsonl (one line per row, appended; finished rows are skipped on a
re-run) and prints each row.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from annotation_loop import copy_scene_without_truth  # noqa: E402

from annotate import Project  # noqa: E402
from annotate.export import export_gt  # noqa: E402
from annotate.suggest import annotation_queue  # noqa: E402
from annotate.table import empty  # noqa: E402
from seg2pose.eval.evaluate import match_nearest  # noqa: E402
from seg2pose.eval.paper_table import evaluate_run  # noqa: E402
from seg2pose.io.atomic import atomic_write_text  # noqa: E402
from seg2pose.io.poses import PoseTable, read_poses  # noqa: E402
from seg2pose.io.run import read_views  # noqa: E402
from seg2pose.io.scene import load_scene  # noqa: E402
from seg2pose.method.pipeline import RunOptions, run_scene  # noqa: E402
from seg2pose.training.demo_models import SHIPPED  # noqa: E402
from seg2pose.training.fine_tune import FineTuneOptions, fine_tune_scene  # noqa: E402
from seg2pose.training.fine_tune_data import scratch_start  # noqa: E402

CAM, CONFIG = "c1", "mono-1"
PER_TRACK = 5  # keyframes per road user (issue 41: 25 keyframes, about 5 road users)


def s2p(*args) -> None:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from seg2pose.cli import main; main()", *map(str, args)],
                       capture_output=True, text=True)
    print(f"$ s2p {' '.join(map(str, args))}   [{time.perf_counter() - t:.0f} s]", file=sys.stderr, flush=True)
    if r.returncode:
        raise SystemExit(f"s2p {args[0]} failed:\n{r.stderr[-2000:]}")


def prep(scene_dir: Path, out: Path) -> Path:
    """Masks from video and rough heights on the scene (marked done), and WORK: the
    annotator's copy without truth."""
    for mark, argv in ((".bg-done", ("masks-from-video", scene_dir, "--camera", CAM, "--force")),
                       (".heights-done", ("heights", scene_dir, "--rough", 2000, "--camera", CAM))):
        if not (scene_dir / mark).exists():
            s2p(*argv)
            (scene_dir / mark).touch()
    work = out / "work"
    if not (work / "scene.json").exists():
        if work.exists():
            shutil.rmtree(work)
        copy_scene_without_truth(scene_dir, work)
    return work


def score(truth_scene, run_dir: Path, baseline_run: Path | None = None) -> dict:
    r = evaluate_run(truth_scene, run_dir, split="test", match="nearest").to_dict()
    out = {"mean_m": r["mean_error"], "n": r["n_matched"], "recall": r["recall"],
           "per_class": r["per_class"]}
    if baseline_run is not None and (baseline_run / "poses.csv").exists():
        out["same_rows"] = same_rows(truth_scene, run_dir, baseline_run)
    return out


def same_rows(truth_scene, run_dir: Path, baseline_run: Path) -> dict:
    """Mean error overall and per truth class on the test-split truth rows that both this run
    and the baseline's match (``match_nearest``, gate 3 m). The plain means compare different
    rows: a network that moves an estimate within 3 m of a road user the baseline missed adds
    a pair of 2-3 m to its class, so a class can look worse than the baseline where it is
    better on every road user both see."""
    gt = read_poses(truth_scene.gt_path).in_frames(truth_scene.split_range("test"))
    got = {}
    for name, d in (("run", run_dir), ("baseline", baseline_run)):
        est = read_poses(d / "poses.csv").in_frames(truth_scene.split_range("test"))
        ie, ig = match_nearest(est, gt)
        got[name] = dict(zip(ig.tolist(), np.linalg.norm(est.xyz[ie, :2] - gt.xyz[ig, :2], axis=1)))
    common = sorted(set(got["run"]) & set(got["baseline"]))
    e = {k: np.array([got[k][i] for i in common]) for k in got}
    cls = gt.cls[common].astype(str) if common else np.zeros(0, str)
    out = {"n": len(common), "mean_m": float(e["run"].mean()) if common else float("nan"),
           "baseline_m": float(e["baseline"].mean()) if common else float("nan"), "per_class": {}}
    for c in sorted(set(cls.tolist())):
        m = cls == c
        out["per_class"][c] = {"n": int(m.sum()), "run_m": float(e["run"][m].mean()),
                               "baseline_m": float(e["baseline"][m].mean())}
    return out


def run(work: Path, run_dir: Path, models: Path | None, split: str | None = "test") -> Path:
    run_scene(load_scene(work), run_dir, RunOptions(config=CONFIG, baseline=models is None,
                                                    models_dir=models, split=split, force=True,
                                                    progress=False, far_residuals="off"))
    return run_dir


def start_folder(name: str, work: Path, out: Path, zero: Path | None) -> Path:
    if name == "shipped":
        return SHIPPED / "bench-seed7"
    if name == "scratch":
        d = out / "start-scratch"
        if not d.exists():
            scratch_start(load_scene(work), d)
        return d
    if name == "zero":
        if zero is None:
            raise SystemExit("--start zero needs --zero-models (a zero-annotation run's models/)")
        return zero
    raise SystemExit(f"unknown start {name}")


def candidates(chooser: str, views, center, test: tuple[int, int], seed: int) -> list:
    keep = np.flatnonzero((views.frame < test[0]) | (views.frame > test[1]))
    q = annotation_queue(views.take(keep), empty(), center, per_track=PER_TRACK, limit=10_000)
    if chooser == "app":
        return q
    rng = np.random.default_rng(seed)
    return [q[i] for i in rng.permutation(len(q))]


def truth_user(truth: PoseTable, cam, frame: int, uv: np.ndarray) -> int | None:
    """The truth row (index) in ``frame`` whose box centre projects nearest ``uv`` (50 px)."""
    rows = np.flatnonzero(truth.frame == frame)
    if not len(rows):
        return None
    c = truth.xyz[rows].copy()
    if truth.size is not None:
        c[:, 2] += truth.size[rows, 2] / 2
    px, _, front = cam.project_points(c)
    d = np.linalg.norm(px - uv, axis=1)
    d[~front] = np.inf
    k = int(np.argmin(d))
    return int(rows[k]) if d[k] <= 50 else None


def annotate_k(work: Path, truth: PoseTable, queue: list, views, k: int) -> dict:
    """A fresh project on WORK with ``k`` keyframes from the queue (see the module docstring);
    exports gt/poses.csv. Returns the counts."""
    for p in (work / "annotations", work / "gt"):
        if p.exists():
            shutil.rmtree(p)
    if k == 0:
        return {"keyframes": 0, "tracks": 0, "actions": 0}
    cam = load_scene(work).cameras[CAM]
    placed, made = 0, set()
    with Project.open(work) as p:
        for c in queue:
            for f in c.frames:
                if placed >= k:
                    break
                v = np.flatnonzero((views.frame == f) & (views.track_id == c.track) & (views.camera == CAM))
                if not len(v):
                    continue
                i = truth_user(truth, cam, f, views.uv[v[0]])
                if i is None:
                    continue
                tid = int(truth.track_id[i])
                if tid not in made:
                    size = truth.size[i] if truth.size is not None else None
                    p.create_track(str(truth.cls[i]), size=size, track_id=tid)
                    made.add(tid)
                if f in p.track(tid).keyframes:
                    continue
                p.set_keyframe(tid, f, float(truth.xyz[i, 0]), float(truth.xyz[i, 1]),
                               float(truth.heading[i]) if np.isfinite(truth.heading[i]) else None)
                placed += 1
            if placed >= k:
                break
        export_gt(p)
    return {"keyframes": placed, "tracks": len(made), "actions": len(made) + 2 * placed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path, help="s2p synth --preset wide --video scene folder")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--start", action="append", choices=["shipped", "scratch", "zero"])
    ap.add_argument("--zero-models", type=Path, help="the scene's zero-annotation models (for --start zero)")
    ap.add_argument("--chooser", action="append", choices=["app", "uniform"])
    ap.add_argument("-k", "--keyframes", type=int, action="append")
    ap.add_argument("--epochs", type=int, default=FineTuneOptions.epochs)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--min-held-out", type=int, default=FineTuneOptions.min_held_out_users,
                    help="hold out road users of a class only from this many annotated ones")
    ap.add_argument("--no-choose", action="store_true",
                    help="no per-class choice of baseline / start / fine-tuned (early stopping instead)")
    ap.add_argument("--min-mask-iou", type=float, default=FineTuneOptions.min_mask_iou,
                    help="annotated masks whose box IoU with the truth's projected box is lower are not trained on")
    ap.add_argument("--folds", type=int, default=FineTuneOptions.folds)
    ap.add_argument("--baseline-min-users", type=int, default=FineTuneOptions.baseline_min_users,
                    help="a class takes the baseline only from this many annotated road users")
    ap.add_argument("--tag", default="", help="suffix of the rows' names (variants)")
    a = ap.parse_args()
    truth_scene = load_scene(a.scene)
    seed = int(truth_scene.extra.get("generator", {}).get("seed", 0))
    out = a.out / a.scene.name
    out.mkdir(parents=True, exist_ok=True)
    work = prep(a.scene, out)
    truth_scene = load_scene(a.scene)
    truth = read_poses(a.scene / "gt" / "poses.csv")
    log = out / "curve.jsonl"
    done = {json.loads(x)["row"] for x in log.read_text().splitlines()} if log.exists() else set()

    def emit(row: dict) -> None:
        row = {"scene_seed": seed, **row}
        print(json.dumps(row), flush=True)
        old = log.read_text() if log.exists() else ""
        atomic_write_text(log, old + json.dumps(row) + "\n")

    if "baseline" not in done:
        emit({"row": "baseline", **score(truth_scene, run(work, out / "runs" / "baseline", None))})
    test = load_scene(work).split_range("test")
    center = load_scene(work).rig.center[:2]
    for start in a.start or ["shipped"]:
        sdir = start_folder(start, work, out, a.zero_models)
        # scratch has nothing to say about what to annotate: it gets the shipped start's queue
        whole = out / "runs" / f"{'shipped' if start == 'scratch' else start}-all"
        if not (whole / "views.csv").exists():
            run(work, whole, start_folder("shipped", work, out, None) if start == "scratch" else sdir,
                split=None)
        if start != "scratch" and f"{start}-0" not in done:
            emit({"row": f"{start}-0", "start": start, "k": 0,
                  **score(truth_scene, whole, out / "runs" / "baseline")})
        views = read_views(whole / "views.csv")
        queues = {c: candidates(c, views, center, test, seed) for c in a.chooser or ["app"]}
        for k in a.keyframes or [25, 10]:  # in the order given: the most wanted first
            for chooser, queue in queues.items():
                name = f"{start}-{chooser}-{k}{a.tag}"
                if k == 0 or name in done:
                    continue
                counts = annotate_k(work, truth, queue, views, k)
                models = out / "models" / name
                if models.exists():
                    shutil.rmtree(models)
                c0, t0 = time.process_time(), time.perf_counter()
                res = fine_tune_scene(load_scene(work), sdir, models,
                                      FineTuneOptions(epochs=a.epochs, threads=a.threads, progress=False,
                                                      min_held_out_users=a.min_held_out,
                                                      choose=not a.no_choose, folds=a.folds,
                                                      baseline_min_users=a.baseline_min_users,
                                                      min_mask_iou=a.min_mask_iou),
                                      cameras=[CAM])
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                emit({"row": name, "start": start, "chooser": chooser, "k": k, **counts,
                      "min_held_out": a.min_held_out, "choose": not a.no_choose, "folds": a.folds,
                      "baseline_min_users": a.baseline_min_users,
                      "min_mask_iou": a.min_mask_iou,
                      "fine_tune_cpu_s": round(cpu), "fine_tune_wall_s": round(wall),
                      "lines": res.lines, **score(truth_scene, run(work, out / "runs" / name, models),
                                                  out / "runs" / "baseline")})


if __name__ == "__main__":
    main()
