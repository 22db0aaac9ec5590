"""Accuracy of multi-camera runs on video input, with and without cross-camera association
(issue 23), on synthetic ``--video`` scenes with truth.

    PYTHONPATH=. .venv/bin/python benches/assoc_figures.py VIDEO_SCENE TRUTH_SCENE --out DIR
        [--input bgsub|coco] [--set KEY=VALUE ...] [--reuse]

VIDEO_SCENE: ``s2p synth -o OUT --frames N --video --seed S``; TRUTH_SCENE: the same seed with
``--no-detector-noise --match all`` (its masks: every visible road user's silhouette, with the
truth's ids). Inputs: ``bgsub`` (``s2p masks-from-video --no-associate``, all cameras) or
``coco`` (the generator's noisy masks as a detector's COCO results without track ids, made as
``benches/video_figures.py`` makes them, through ``s2p import-detections --no-associate`` per
camera). The tracker's masks are kept in DIR/<input>-S.tracker (``--reuse`` starts from them);
then ``s2p associate`` (settings from ``--set``).

Configurations: each camera alone (its tracker's masks: what the lens gives by itself), and
stereo-10, tri-I, tri-T and all five cameras, before association (``--fuse-unassociated``) and
after. Each run: ``s2p run --baseline``; scored against the truth *the configuration's cameras
see* (gt/poses.csv rows whose road user has a truth mask of >= 150 px in one of its cameras in
that frame), per frame one to one by ground distance (Hungarian) within 3 m (the default --gate
of s2p eval): recall, precision,
mean error of the pairs; cross-camera id consistency as ``s2p eval`` reports it (views paired
with the truth per camera and frame; share of a road user's views in a frame that carry its
majority id).

Each associated run is also compared with its cameras alone *on the same truth* (the rows its
cameras see), in ``same_truth``: per camera alone its recall, precision and mean error against
the configuration's truth (a lens scored on its own truth is not charged for road users only the
other lenses see, so its recall there is not comparable with the configuration's), and the
*common matched set* -- truth rows that the configuration's run and every one of its cameras
alone matched -- with each run's mean error on it (the same poses for every run: by the triangle
inequality the mean of views is no farther from the truth than their mean distance).

``--rescore``: no s2p call; score the runs already in DIR/<input>-S/out again (the masks and runs
of the last call) and write the rows file.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from video_figures import coco_from_masks, fresh_scene, s2p  # noqa: E402

from seg2pose.eval.evaluate import id_consistency, match_nearest  # noqa: E402
from seg2pose.io.mots import iter_mots  # noqa: E402
from seg2pose.io.poses import (
    PoseTable,  # noqa: E402
    read_poses,  # noqa: E402
)
from seg2pose.io.run import read_run_poses, read_views  # noqa: E402
from seg2pose.structures.masks import rle_stats  # noqa: E402

CAMERAS = ["c0", "c1", "c2", "c3", "c4"]
MULTI = {"stereo-10": ["c1", "c3"], "tri-I": ["c0", "c1", "c2"], "tri-T": ["c0", "c2", "c4"],
         "all": CAMERAS}
GATE = 3.0


def visible(truth: Path) -> dict[str, set]:
    """camera -> {(frame, road user)} with a truth mask of >= 150 px."""
    out = {}
    for c in CAMERAS:
        s = set()
        for f, t in iter_mots(truth / "masks" / f"{c}.txt"):
            area, _, _ = rle_stats(t.rles, t.height, t.width)
            s |= {(f, int(i)) for i in t.track_id[area >= 150]}
        out[c] = s
    return out


def seen_rows(truth: Path, vis: dict, cams: list[str]) -> PoseTable:
    """The rows of gt/poses.csv that one of ``cams`` sees (``visible``)."""
    gt = read_poses(truth / "gt" / "poses.csv")
    seen = set().union(*(vis[c] for c in cams))
    keep = np.array([(int(f), int(i)) in seen for f, i in zip(gt.frame, gt.track_id)], bool)
    return gt.take(np.flatnonzero(keep))


def same_truth(fused: PoseTable, alone: dict[str, PoseTable], gtv: PoseTable,
               gate: float = GATE) -> dict:
    """A configuration's run ``fused`` and its cameras alone (``alone``: camera -> poses) on
    the same truth ``gtv``: per camera its recall, precision and mean error there (``alone``);
    the truth rows every one of the runs matched (``common``: n) with the mean error of each
    run on them (``error_m`` the configuration's, ``alone_error_m`` per camera,
    ``alone_mean_error_m`` their mean)."""
    def pairs(est: PoseTable) -> dict[int, float]:
        ie, ig = match_nearest(est, gtv, gate)
        err = np.linalg.norm(est.xyz[ie, :2] - gtv.xyz[ig, :2], axis=1)
        return dict(zip(ig.tolist(), err.tolist()))

    pf = pairs(fused)
    pa = {c: pairs(p) for c, p in alone.items()}
    out = {c: {"recall": len(pa[c]) / max(len(gtv), 1),
               "precision": len(pa[c]) / max(len(alone[c]), 1),
               "error_m": float(np.mean(list(pa[c].values()))) if pa[c] else float("nan")}
           for c in alone}
    common = sorted(set(pf).intersection(*(set(d) for d in pa.values())))
    mean = lambda d: float(np.mean([d[g] for g in common])) if common else float("nan")  # noqa: E731
    per_cam = {c: mean(pa[c]) for c in alone}
    return {"alone": out, "common": {"n": len(common), "error_m": mean(pf), "alone_error_m": per_cam,
                                     "alone_mean_error_m": float(np.mean(list(per_cam.values())))}}


def score(scene: Path, run: Path, truth: Path, vis: dict, cams: list[str]) -> dict:
    gt = read_poses(truth / "gt" / "poses.csv")
    gtv = seen_rows(truth, vis, cams)
    est = read_run_poses(run)
    ie, ig = match_nearest(est, gtv, GATE)
    err = np.linalg.norm(est.xyz[ie, :2] - gtv.xyz[ig, :2], axis=1)
    v = read_views(run / "views.csv")
    cons, n_multi = (id_consistency(v.frame, v.camera, v.track_id, v.normal[:, :2] + v.residual, gt, 3.0)
                     if len(cams) > 1 else (float("nan"), 0))
    return {"recall": len(ie) / max(len(gtv), 1), "precision": len(ie) / max(len(est), 1),
            "error_m": float(err.mean()) if len(err) else float("nan"), "n_truth": len(gtv),
            "n_est": len(est), "id_consistency": cons, "n_multi_view": n_multi}


def add_configs(scene: Path) -> None:
    p = scene / "scene.json"
    d = json.loads(p.read_text())
    d["configs"].update({f"cam-{c}": [c] for c in CAMERAS})
    d["configs"]["all"] = CAMERAS
    p.write_text(json.dumps(d, indent=1))


def prepare(video: Path, out: Path, kind: str, seed: int, reuse: bool) -> Path:
    work = out / f"{kind}-{seed}"
    keep = out / f"{kind}-{seed}.tracker"
    if reuse and keep.exists():
        if not (work / "scene.json").exists():       # the tracker's masks copied to a new DIR
            fresh_scene(video, work)
            add_configs(work)
        shutil.rmtree(work / "masks", ignore_errors=True)
        shutil.copytree(keep, work / "masks")
        return work
    fresh_scene(video, work)
    add_configs(work)
    if kind == "bgsub":
        s2p("masks-from-video", str(work), "--no-progress", "--no-associate")
    else:
        for c in CAMERAS:
            js = out / f"coco-{seed}-{c}.json"
            coco_from_masks(video / "masks" / f"{c}.txt", js, seed)
            s2p("import-detections", str(work), str(js), "--camera", c, "--no-associate")
    if keep.exists():
        shutil.rmtree(keep)
    shutil.copytree(work / "masks", keep)
    return work


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video_scene", type=Path)
    ap.add_argument("truth_scene", type=Path)
    ap.add_argument("--out", type=Path, default=Path("/tmp/assoc_figures"))
    ap.add_argument("--input", choices=["bgsub", "coco"], default="bgsub")
    ap.add_argument("--set", action="append", default=[], help="an s2p associate setting")
    ap.add_argument("--reuse", action="store_true", help="start from the kept tracker masks")
    ap.add_argument("--skip-before", action="store_true", help="no runs before association")
    ap.add_argument("--skip-alone", action="store_true",
                    help="no runs of the cameras alone (kept from an earlier call)")
    ap.add_argument("--confirm", type=float, default=None, help="s2p run --confirm for the associated runs")
    ap.add_argument("--rescore", action="store_true", help="no s2p call: score the runs in DIR/<input>-S/out again")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    seed = json.loads((a.video_scene / "scene.json").read_text())["extra"]["generator"]["seed"]
    work = a.out / f"{a.input}-{seed}" if a.rescore else prepare(a.video_scene, a.out, a.input, seed, a.reuse)
    vis = visible(a.truth_scene)
    rows = []

    def run(name: str, cams: list[str], stage: str, *extra: str) -> None:
        d = work / "out" / f"{stage}-{name}"
        if not a.rescore:
            s2p("run", str(work), "-o", str(d), "-c", name if name in MULTI else f"cam-{name}",
                "--baseline", "--force", *extra)
        elif not d.exists():
            return
        r = {"seed": seed, "input": a.input, "stage": stage, "config": name,
             **score(work, d, a.truth_scene, vis, cams)}
        if stage == "associated":
            r["same_truth"] = same_truth(read_run_poses(d), {c: read_run_poses(work / "out" / f"alone-{c}")
                                                             for c in cams},
                                         seen_rows(a.truth_scene, vis, cams))
        rows.append(r)
        print(json.dumps(r), flush=True)

    alone_file = a.out / f"alone-{a.input}-{seed}.json"
    if a.skip_alone and alone_file.exists() and not a.rescore:
        rows += json.loads(alone_file.read_text())
    else:
        for c in CAMERAS:
            run(c, [c], "alone")
        alone_file.write_text(json.dumps(rows, indent=1))
    if not a.skip_before:
        for name, cams in MULTI.items():
            run(name, cams, "unassociated", "--fuse-unassociated")
    sets = [x for kv in a.set for x in ("--set", kv)]
    if not a.rescore:
        print(s2p("associate", str(work), "--force", *sets).strip(), flush=True)
    conf = () if a.confirm is None else ("--confirm", str(a.confirm))
    for name, cams in MULTI.items():
        run(name, cams, "associated", *conf)
    tag = "-".join(x.replace("=", "") for x in a.set + ([f"confirm{a.confirm}"] if conf else [])) or "default"
    (a.out / f"rows-{a.input}-{seed}-{tag}.json").write_text(json.dumps(rows, indent=1))
    for name, cams in MULTI.items():
        alone = [r for r in rows if r["stage"] == "alone" and r["config"] in cams]
        r = next(r for r in rows if r["stage"] == "associated" and r["config"] == name)
        best = max(x["recall"] for x in alone)
        mean_err = float(np.mean([x["error_m"] for x in alone]))
        print(f"{name:10s} recall {r['recall']:.3f} (best mono {best:.3f}) precision "
              f"{r['precision']:.3f} error {r['error_m']:.3f} (mono mean {mean_err:.3f}) "
              f"id consistency {r['id_consistency']:.3f}")


if __name__ == "__main__":
    main()
