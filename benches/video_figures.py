"""Accuracy figures of the video path (issue 13) on synthetic ``--video`` scenes with truth.

    .venv/bin/python benches/video_figures.py VIDEO_SCENE TRUTH_SCENE [--camera c1] [--out DIR]
        [--skip-bgsub | --skip-coco]

VIDEO_SCENE: ``s2p synth -o OUT --video --seed S`` (its masks/ hold the generator's
detector-like masks, with noise); TRUTH_SCENE: the same seed with ``--no-noise --match all``
(rendered silhouettes of every visible road user: the truth masks). Two inputs are measured:

1. background subtraction: ``masks-from-video`` (MOG2 + components + tracker + size classes);
2. detector-style COCO: the generator's noisy masks (``coco-noisy``; their own recall against
   the truth is printed for reference) or the clean truth masks (``coco-clean``) as a COCO
   results file without track ids
   (pedestrian -> person, car -> car, a bicyclist split into a person (top 60 %) and a bicycle
   (bottom 55 %) mask that overlap like a rider's legs and the frame, scores U(0.5, 1), 5 %
   duplicates with a lower score, 5 % false positives
   below the 0.5 threshold), through ``import-detections`` (threshold, NMS, bicyclist merge,
   tracker).

For each: recall of truth masks >= 150 px at IoU >= 0.5, precision, identities kept across
consecutive matched frames and ID switches per 100 truth tracks, classes right for cars vs
pedestrians; the standard tracking metrics of the masks (HOTA, IDF1, MOTSA on mask IoU, truth
masks under 150 px as ignore regions: ``s2p eval --truth-masks``); then ``s2p run --baseline``
on the camera's mono configuration, ``s2p eval --match nearest`` (positions against
gt/poses.csv) and, from the same ``s2p eval``, the tracking metrics of its world tracks
(similarity 1 - d / 2 m) against the truth in view of the camera.
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

from seg2pose.eval.mask_eval import score_masks  # noqa: E402
from seg2pose.io.mots import iter_mots, read_mots  # noqa: E402
from seg2pose.structures.masks import decode, encode  # noqa: E402


def fresh_scene(src: Path, dst: Path) -> None:
    """A copy of scene ``src`` without masks (scene.json, ground points, truth; video linked)."""
    if dst.exists():
        shutil.rmtree(dst)
    (dst / "masks").mkdir(parents=True)
    for name in ("scene.json", "ground_points.csv"):
        shutil.copy2(src / name, dst / name)
    shutil.copytree(src / "gt", dst / "gt")
    (dst / "video").mkdir()
    for v in (src / "video").iterdir():
        (dst / "video" / v.name).hardlink_to(v)


def coco_from_masks(masks: Path, out: Path, seed: int) -> int:
    """Detector-style COCO results (see the module docstring). Returns the records written."""
    rng = np.random.default_rng(seed)
    recs = []
    for f, t in iter_mots(masks):
        for i in range(len(t)):
            cls, r = int(t.class_id[i]), t.rles[i]
            score = float(rng.uniform(0.5, 1.0))
            seg = {"size": [t.height, t.width], "counts": r.decode()}
            if cls == 2:  # bicyclist -> person (top 60 %) + bicycle (bottom 55 %): the
                # rider's legs overlap the bicycle, as in a detector's output (IoU ~0.15)
                m = decode(r, t.height, t.width)
                rows = np.flatnonzero(m.any(axis=1))
                span = rows[-1] - rows[0] + 1
                top, bottom = m.copy(), m.copy()
                top[rows[0] + int(0.60 * span):] = 0
                bottom[:rows[0] + int(0.45 * span)] = 0
                for part, cat in ((top, 1), (bottom, 2)):
                    if part.any():
                        recs.append({"image_id": f, "category_id": cat, "score": score,
                                     "segmentation": {"size": [t.height, t.width],
                                                      "counts": encode(part).decode()}})
                continue
            cat = {1: 1, 3: 3}.get(cls, 1)
            recs.append({"image_id": f, "category_id": cat, "score": score, "segmentation": seg})
            if rng.random() < 0.05:
                recs.append({"image_id": f, "category_id": cat, "score": score * 0.9, "segmentation": seg})
            if rng.random() < 0.05:
                recs.append({"image_id": f, "category_id": 3 - cat + 1 if cat == 1 else 1,
                             "score": float(rng.uniform(0.05, 0.45)), "segmentation": seg})
    out.write_text(json.dumps(recs))
    return len(recs)


def recall_moving_still(truth: Path, est: Path, cam: str, step_m: float = 0.03) -> dict:
    """Recall (IoU >= 0.5, truth masks >= 150 px) split by whether the road user moved more
    than ``step_m`` metres into or out of the frame (gt/poses.csv): background subtraction
    cannot see road users that stand still for most of the video."""
    from scipy.optimize import linear_sum_assignment

    from seg2pose.io.poses import read_poses
    from seg2pose.structures.masks import iou, rle_stats

    gt = read_poses(truth / "gt" / "poses.csv")
    o = np.lexsort((gt.frame, gt.track_id))
    tid, fr, xy = gt.track_id[o], gt.frame[o], gt.xyz[o, :2]
    same = np.r_[False, tid[1:] == tid[:-1]]
    step = np.where(same, np.r_[0, np.linalg.norm(np.diff(xy, axis=0), axis=1)], 0.0)
    moved = np.maximum(step, np.r_[step[1:], 0.0]) > step_m
    moving = {(int(f), int(t)): bool(m) for f, t, m in zip(fr, tid, moved)}
    est_frames = {f: t for f, t in iter_mots(est / "masks" / f"{cam}.txt")}
    hit = {True: 0, False: 0}
    tot = {True: 0, False: 0}
    for f, tt in iter_mots(truth / "masks" / f"{cam}.txt"):
        area, _, _ = rle_stats(tt.rles, tt.height, tt.width)
        ok = np.zeros(len(tt), bool)
        if f in est_frames:
            m = iou(tt.rles, est_frames[f].rles, tt.height, tt.width)
            r, c = linear_sum_assignment(-m)
            ok[r[m[r, c] >= 0.5]] = True
        for i in np.flatnonzero(area >= 150):
            k = moving.get((f, int(tt.track_id[i])), False)
            tot[k] += 1
            hit[k] += int(ok[i])
    return {"recall_moving": hit[True] / max(tot[True], 1), "n_moving": tot[True],
            "recall_still": hit[False] / max(tot[False], 1), "n_still": tot[False]}


def s2p(*args: str) -> str:
    r = subprocess.run([sys.executable, "-c", "from seg2pose.cli import main; main()", *args],
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"s2p {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")
    return r.stdout


def report(name: str, scene: Path, truth: Path, cam: str, config: str) -> dict:
    s = score_masks(iter_mots(truth / "masks" / f"{cam}.txt"), iter_mots(scene / "masks" / f"{cam}.txt"))
    est = read_mots(scene / "masks" / f"{cam}.txt")
    s2p("run", str(scene), "-o", str(scene / "out" / "baseline"), "-c", config, "--baseline", "--force")
    # tracking metrics of the masks (mask IoU; truth masks under 150 px, the smallest blob
    # background subtraction reports, are ignore regions) through s2p eval --json
    ev = json.loads(s2p("eval", str(scene), "--run", str(scene / "out" / "baseline"), "--match", "nearest",
                        "--truth-masks", str(truth / "masks" / f"{cam}.txt"), "--ignore-below", "150", "--json"))
    mk, wt = ev["masks"][cam], ev["tracking"]     # the masks', and the run's world tracks' (in view of c1)
    row = {"input": name, "recall": s.recall, "precision": s.precision,
           "identity_kept": s.identity_kept, "switches_per_100": s.switches_per_100,
           "truth_tracks": s.tracks, "est_tracks": int(len(np.unique(est.track_id))),
           "class_car_ped": s.class_accuracy([1, 3]), "class_all": s.class_accuracy([1, 2, 3]),
           "baseline_m": ev["mean_error"], "matched": f"{ev['n_matched']}/{ev['n_gt']}",
           **{f"masks_{k}": mk[k] for k in ("HOTA", "DetA", "AssA", "LocA", "IDF1", "MOTSA", "IDSW", "FP", "FN")},
           **{f"world_{k}": wt[k] for k in ("HOTA", "DetA", "AssA", "LocA", "IDF1", "MOTA", "IDSW", "FP", "FN")},
           **recall_moving_still(truth, scene, cam)}
    print(json.dumps(row))
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video_scene", type=Path)
    ap.add_argument("truth_scene", type=Path)
    ap.add_argument("--camera", default="c1")
    ap.add_argument("--config", default="mono-1")
    ap.add_argument("--out", type=Path, default=Path("/tmp/video_figures"))
    ap.add_argument("--skip-bgsub", action="store_true", help="only the COCO inputs")
    ap.add_argument("--skip-coco", action="store_true", help="only the background subtraction")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    seed = json.loads((a.video_scene / "scene.json").read_text())["extra"]["generator"]["seed"]
    rows = []
    s = score_masks(iter_mots(a.truth_scene / "masks" / f"{a.camera}.txt"),
                    iter_mots(a.video_scene / "masks" / f"{a.camera}.txt"))
    print(json.dumps({"input": "generator noisy masks (reference)", "recall": s.recall,
                      "precision": s.precision}))
    bg = a.out / f"bgsub-{seed}"
    if not a.skip_bgsub:
        fresh_scene(a.video_scene, bg)
        t = time.perf_counter()
        s2p("masks-from-video", str(bg), "--camera", a.camera, "--no-progress")
        print(f"masks-from-video: {time.perf_counter() - t:.0f} s")
        rows.append(report("bg-sub", bg, a.truth_scene, a.camera, a.config))
    # detector-style input from the generator's noisy masks, and from the clean truth masks
    for name, src in () if a.skip_coco else (("coco-noisy", a.video_scene), ("coco-clean", a.truth_scene)):
        det = a.out / f"{name}-{seed}"
        fresh_scene(a.video_scene, det)
        n = coco_from_masks(src / "masks" / f"{a.camera}.txt", a.out / f"{name}-{seed}.json", seed)
        print(f"{name}: {n} COCO records")
        s2p("import-detections", str(det), str(a.out / f"{name}-{seed}.json"), "--camera", a.camera)
        rows.append(report(name, det, a.truth_scene, a.camera, a.config))
    (a.out / f"figures-{seed}.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
