"""Per-track heights (``s2p run --track-heights``) against the same runs without them, from run
folders of all cameras: each configuration's views are taken from the run's views.csv, fitted
(``seg2pose.method.track_heights``) with each setting, fused (with and without smoothing) and
scored against the truth on the run's split; mean error per class, metres.

    .venv/bin/python benches/track_heights.py RUN [RUN ...] [--configs mono-1,tri-I,all]
        [--smooth 0,4] [--grid] [--json OUT]

RUN: an ``s2p run`` folder of every camera of its scene (no -c), baseline or Seg2PoseNet.
``--grid``: the settings grid used to choose the defaults (prior x huber x min_spread, and the smoothness term);
without it, the defaults only. Rows: seed, config, smooth, setting; columns: mean error of the
run without correction, with it, their ratio, and the ratio per class.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

from seg2pose.eval.evaluate import evaluate
from seg2pose.io.poses import read_poses
from seg2pose.io.run import read_run_meta, read_views
from seg2pose.io.scene import load_scene
from seg2pose.method.fusion import fuse
from seg2pose.method.track_heights import DEFAULT_SETTINGS, TrackHeightSettings, apply_track_heights

CLASSES = ("pedestrian", "bicyclist", "car")


def grid() -> list[TrackHeightSettings]:
    out = [DEFAULT_SETTINGS]
    for prior, huber, spread in itertools.product((1.0, 10.0, 100.0), (0.1, 0.3), (0.0, 0.1)):
        s = TrackHeightSettings(prior=prior, huber=huber, min_spread=spread, class_prior=())
        if s != DEFAULT_SETTINGS:
            out.append(s)
    out.append(TrackHeightSettings(smooth=1.0))  # the smoothness term on top of the default
    out.append(TrackHeightSettings(class_prior=()))  # one prior for every class
    return out


def label(s: TrackHeightSettings) -> str:
    cp = "".join(f",{c[:3]}:{v:g}" for c, v in s.class_prior)
    return f"prior={s.prior:g}{cp} huber={s.huber:g} spread={s.min_spread:g} smooth={s.smooth:g}"


def score(scene, views, smooth: int, fr) -> tuple[float, dict]:
    est = fuse(views, scene, smooth)
    gt = read_poses(scene.gt_path)
    r = evaluate(est, gt, scene.rig.center[:2], frame_range=fr)
    return r.mean_error, {c: r.per_class.get(c, float("nan")) for c in CLASSES}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--configs", default="mono-1,tri-I,all")
    ap.add_argument("--smooth", default="0,4")
    ap.add_argument("--grid", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--one-prior", action="store_true", help="also the default with one prior for every class")
    a = ap.parse_args()
    settings = grid() if a.grid else [DEFAULT_SETTINGS]
    if a.one_prior and not a.grid:
        settings.append(TrackHeightSettings(class_prior=()))
    rows = []
    print(f"{'run':<22} {'config':<7} {'sm':>2}  {'setting':<44} {'before m':>8} {'after m':>8} "
          f"{'ratio':>6}  " + "  ".join(f"{c[:5]:>6}" for c in CLASSES))
    for run in a.runs:
        run = Path(run)
        meta = read_run_meta(run)
        scene = load_scene((run / meta["scene"]).resolve())
        all_views = read_views(run / "views.csv")
        fr = tuple(meta["frame_range"]) if meta.get("frame_range") else None
        for cfg in a.configs.split(","):
            cams = list(scene.cameras) if cfg == "all" else scene.rig.configs[cfg]
            views = all_views.of_cameras(cams)
            fitted = {label(s): apply_track_heights(scene, views, s)[0] for s in settings}
            for sm in (int(x) for x in a.smooth.split(",")):
                e0, c0 = score(scene, views, sm, fr)
                for s in settings:
                    e1, c1 = score(scene, fitted[label(s)], sm, fr)
                    rows.append({"run": run.name, "config": cfg, "smooth": sm, "setting": label(s),
                                 "before": e0, "after": e1, "class_before": c0, "class_after": c1})
                    print(f"{run.name:<22} {cfg:<7} {sm:>2}  {label(s):<44} {e0:8.4f} {e1:8.4f} "
                          f"{e1 / e0:6.3f}  " + "  ".join(f"{c1[c] / c0[c]:6.3f}" for c in CLASSES),
                          flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
