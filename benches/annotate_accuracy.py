"""Accuracy of clicked ground truth: a scripted annotator clicks, in centre mode, the pixel where
each true road user's box centre projects (a careful human), keyframes every ``--every``
frames (>= 5 per road user), in the camera that sees the road user largest; the engine turns
each click into a keyframe (``Project.place_from_pixel``) and interpolates between them.

Reported per class over all road users of each seed: the keyframes' distance to the truth
(mean, max) and the mean distance over the annotated span (every frame), for the two heights
at which the click's ray may meet the world:

- ``half``: half the track's box height (the class's typical size: the box centre's height
  when the road user is of typical size),
- ``default``: the class's default height (``scene.json``), what the normal position of a
  mask uses (paper 3.2) and what the app's centre mode used before,
- ``own``: half the road user's own height (the annotator set the track's size to the road
  user's),
- ``surface`` (a diagnostic): as ``own``, but the click is where the centre would be over
  the engine's ground model (eq. 1) rather than over the true ground: what is left is the
  pixel and the interpolation; the difference to ``own`` is the ground model's error.

Clicks land on pixel centres (the annotator's pixel: u, v rounded to k + 0.5), or with
``--zoom Z`` on a grid Z times finer (the annotator zoomed the camera view in Z times). Seeds
201 and 202 are not used by any test.

    python benches/annotate_accuracy.py [--seeds 201 202] [--every 25] [--frames 150] [--zoom 1 4]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def best_camera(scene, xyz_centre: np.ndarray, size: np.ndarray):
    """(camera name, pixel (2,)) of the camera that sees the box centre inside its image with
    the box largest (distance as a proxy), or (None, None)."""
    best = (None, None, np.inf)
    for name, cam in scene.cameras.items():
        uv, depth, front = cam.project_points(xyz_centre[None])
        u, v = uv[0]
        if not front[0] or not (0.02 * cam.width < u < 0.98 * cam.width and
                                0.02 * cam.height < v < 0.98 * cam.height):
            continue
        d = float(np.linalg.norm(xyz_centre - cam.center))
        if d < best[2]:
            best = (name, uv[0], d)
    return best[0], best[1]


def annotate_seed(seed: int, frames: int, every: int, work: Path, zooms=(1,)) -> dict:
    """Per (height mode, class): lists of keyframe errors and span mean errors (metres)."""
    from annotate import Project
    from seg2pose.io.poses import read_poses
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = work / f"seed{seed}"
    generate_scene(root, SynthOptions(preset="small", frames=frames, seed=seed, video=False, progress=False,
                   workers=1))
    scene = load_scene(root)
    gt = read_poses(scene.gt_path)
    sizes = scene.class_sizes()
    defaults = scene.default_heights()
    out = {}
    for mode in [(h, z) for z in zooms for h in ("half", "default", "own", "surface")]:
        mode, zoom = f"{mode[0]} x{mode[1]}", mode[1]
        import shutil

        shutil.rmtree(root / "annotations", ignore_errors=True)
        with Project.open(scene) as p:
            for tid in np.unique(gt.track_id):
                rows = np.flatnonzero(gt.track_id == tid)
                rows = rows[np.argsort(gt.frame[rows])]
                fr = gt.frame[rows]
                # one stretch of consecutive frames (the first), long enough for 5 keyframes
                cut = np.flatnonzero(np.diff(fr) != 1)
                end = cut[0] + 1 if len(cut) else len(fr)
                rows, fr = rows[:end], fr[:end]
                if len(fr) < 4 * every + 1:
                    continue
                cls = str(gt.cls[rows[0]])
                size = np.asarray(sizes[cls], float)
                height = size[2] / 2 if mode.startswith("half") else float(defaults[cls])
                own = mode.startswith(("own", "surface"))  # the track has the user's own size
                surface = mode.startswith("surface")
                t = p.create_track(cls).track
                picks = list(range(0, len(fr), every))
                if picks[-1] != len(fr) - 1:
                    picks.append(len(fr) - 1)
                placed = []
                for i in picks:
                    x, y, z = gt.xyz[rows[i]]
                    h_true = gt.size[rows[i], 2] if gt.size is not None else size[2]
                    if surface:  # where the centre would be over the engine's ground model
                        z = float(scene.ground.height(np.array([[x, y]]))[0])
                    centre = np.array([x, y, z + h_true / 2])  # the truth's own box centre
                    cam, uv = best_camera(scene, centre, size)
                    if cam is None:
                        continue
                    pix = (np.floor(uv * zoom) + 0.5) / zoom  # the annotator's (zoomed) pixel
                    p.place_from_pixel(t, int(fr[i]), cam, pix,
                                       height=h_true / 2 if own else height)
                    k = p.track(t).keyframes[int(fr[i])]
                    placed.append(float(np.hypot(k.x - x, k.y - y)))
                if len(placed) < 5:
                    p.delete_track(t)
                    continue
                tab = p.track_poses(t)
                sel = np.isin(fr, tab.frame)
                ref = gt.xyz[rows[sel], :2]
                est = tab.xyz[np.searchsorted(tab.frame, fr[sel]), :2]
                d = out.setdefault((mode, cls), {"kf": [], "span": []})
                d["kf"] += placed
                d["span"].append(float(np.linalg.norm(est - ref, axis=1).mean()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[201, 202])
    ap.add_argument("--every", type=int, default=25)
    ap.add_argument("--frames", type=int, default=150, help="frames per split of the scene")
    ap.add_argument("--zoom", type=int, nargs="+", default=[1, 4])
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="annot_acc_"))
    res = {s: annotate_seed(s, args.frames, args.every, work, args.zoom) for s in args.seeds}
    print(f"scripted annotator, centre mode, keyframes every {args.every} frames; per seed "
          f"(road users): keyframe error mean / max, span mean error (mean over road users, max)")
    keys = sorted({k for r in res.values() for k in r})
    for mode, cls in keys:
        parts = []
        for s in args.seeds:
            d = res[s].get((mode, cls))
            if d is None:
                parts.append(f"seed {s}: -")
                continue
            kf, sp = np.array(d["kf"]), np.array(d["span"])
            parts.append(f"seed {s} ({len(sp)}): kf {kf.mean():.3f} / {kf.max():.3f} m, "
                         f"span {sp.mean():.3f} m (max {sp.max():.3f})")
        print(f"  {mode:10s} {cls:10s} " + "; ".join(parts))


if __name__ == "__main__":
    main()
