"""The annotation loop on a synthetic scene: annotate through the API with keyframes every N
frames taken from the truth, export ground truth, and (optionally) train Seg2PoseNet on it and on
the full truth and compare both on the test split against the full truth.

    s2p synth /tmp/loop/truth --preset small && s2p heights /tmp/loop/truth
    python benches/annotation_loop.py /tmp/loop/truth /tmp/loop/annot --every 25
    # then (see docs/RESULTS.md, "Annotation loop"): s2p train ... on both scenes, s2p run, s2p eval

Step 1 copies the scene folder without its ground truth, opens it as an annotation project and,
for every true road user, creates a track (class, size) and puts keyframes at the first frame
of every stretch it is seen, every ``--every`` frames after, and at the stretch's last frame
(position and heading from the truth); gaps between stretches are marked ``outside``. Step 2
exports ``gt/poses.csv`` (source column). It prints how far the interpolation lies from the
truth per class (mean / 95th percentile, metres, every annotated frame) and the time taken.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from annotate import Project
from annotate.export import export_gt
from seg2pose.io.poses import PoseTable, read_poses
from seg2pose.io.scene import SCENE_FILE, load_scene


def copy_scene_without_truth(src: Path, dst: Path) -> None:
    """scene.json, ground points, masks and video of ``src`` into a new folder ``dst``."""
    if dst.exists():
        raise SystemExit(f"{dst} exists; remove it first")
    scene = load_scene(src)
    dst.mkdir(parents=True)
    shutil.copy2(src / SCENE_FILE, dst / SCENE_FILE)
    shutil.copy2(src / scene.ground_file, dst / scene.ground_file)
    for sub in ("masks", "video"):
        if (src / sub).exists():
            shutil.copytree(src / sub, dst / sub)


def stretches(frames: np.ndarray) -> list[np.ndarray]:
    """Runs of consecutive frames (sorted (N,) ints) as a list of arrays."""
    return np.split(frames, np.flatnonzero(np.diff(frames) > 1) + 1) if len(frames) else []


def annotate_from_truth(project: Project, truth: PoseTable, every: int) -> int:
    """Keyframes every ``every`` frames from the truth, through the public edit API; returns
    the number of keyframes placed."""
    n = 0
    for tid in np.unique(truth.track_id).tolist():
        rows = np.flatnonzero(truth.track_id == tid)
        rows = rows[np.argsort(truth.frame[rows])]
        size = truth.size[rows[0]] if truth.size is not None else None
        project.create_track(str(truth.cls[rows[0]]), size=size, track_id=tid)
        parts = stretches(truth.frame[rows])
        for part in parts:
            pick = np.unique(np.r_[np.arange(part[0], part[-1] + 1, every), part[-1]])
            for f in pick.tolist():
                i = rows[np.searchsorted(truth.frame[rows], f)]
                project.set_keyframe(tid, f, truth.xyz[i, 0], truth.xyz[i, 1], truth.heading[i])
                n += 1
        for a, b in zip(parts[:-1], parts[1:]):
            project.mark(tid, int(a[-1]) + 1, int(b[0]) - 1, "outside")
    return n


def interpolation_error(annot: PoseTable, truth: PoseTable) -> dict[str, tuple[float, float, int]]:
    """Class -> (mean, 95th percentile, count) of the ground-plane distance, metres, between
    annotated and true positions of the same road user in the same frame."""
    key = lambda t: t.frame.astype(np.int64) * 1_000_003 + t.track_id  # noqa: E731
    ka, kt = key(annot), key(truth)
    common, ia, it = np.intersect1d(ka, kt, return_indices=True)
    d = np.linalg.norm(annot.xyz[ia, :2] - truth.xyz[it, :2], axis=1)
    cls = truth.cls[it]
    out = {c: (float(d[cls == c].mean()), float(np.percentile(d[cls == c], 95)), int((cls == c).sum()))
           for c in np.unique(cls)}
    out["all"] = (float(d.mean()), float(np.percentile(d, 95)), len(d))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("truth", type=Path, help="synthetic scene folder with the full truth")
    ap.add_argument("out", type=Path, help="new scene folder for the annotated copy")
    ap.add_argument("--every", type=int, default=25, help="keyframe spacing, frames")
    a = ap.parse_args(argv)
    truth = read_poses(a.truth / "gt" / "poses.csv")
    copy_scene_without_truth(a.truth, a.out)
    t0 = time.perf_counter()
    with Project.open(a.out) as p:
        n = annotate_from_truth(p, truth, a.every)
        t1 = time.perf_counter()
        path = export_gt(p)
        annot = read_poses(path)
    t2 = time.perf_counter()
    src = {s: int((annot.source == s).sum()) for s in ("keyframe", "interpolated", "occluded")}
    print(f"{len(np.unique(truth.track_id))} road users, {n} keyframes every {a.every} frames "
          f"({t1 - t0:.1f} s through the API, one journalled edit each); exported {path}: "
          f"{len(annot)} rows {src} in {t2 - t1:.2f} s")
    print(f"truth rows {len(truth)}, annotated rows {len(annot)}")
    for c, (mean, p95, cnt) in interpolation_error(annot, truth).items():
        print(f"interpolation vs truth  {c:11s} mean {mean:.3f} m  p95 {p95:.3f} m  ({cnt} poses)")


if __name__ == "__main__":
    sys.exit(main())
