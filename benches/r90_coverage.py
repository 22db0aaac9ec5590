"""How good the error bars r90_m are on held-out scenes (issue 25): calibrated on the val split
of one or more tuning scenes (or of the held-out scenes themselves: their val splits are not
scored), applied to the test split of held-out scenes, scored per class (coverage, mean r90_m /
mean error, Spearman of r90_m with the error, and the 5-95 % range of the coverage when the
test split's road users are drawn again: how much of a miss is the few road users).

    .venv/bin/python benches/r90_coverage.py OUT --held SCENE [--held SCENE ...]
        [--tune SCENE ...] [--cal tune|own|others|all ...] [--configs mono-1,tri-I]
        [--models DIR [--models DIR ...] | --scene-models NAME] [--smooth N]

``--cal`` (repeatable; default ``tune``): where each held-out scene's bars are calibrated --
``tune`` the val splits of the ``--tune`` scenes together; ``own`` its own val split (the user
with annotated val frames); ``others`` the val splits of the other ``--held`` scenes (the user
without truth on this scene: a zero-annotation run); ``all`` every ``--held`` scene's val
split. ``--own-val`` is ``--cal tune --cal own``.

Per configuration, every step is the ``s2p`` command a user types (printed as it runs):
``s2p run --split val``, ``s2p calibrate-errors`` on those runs, then ``s2p run --split test --r90``
and ``s2p eval --json`` on each held-out scene. Without ``--models`` the runs are the
baseline; ``--models`` repeated gives an ensemble (its spread is a cue); ``--scene-models
NAME`` runs each scene with its own models, SCENE/NAME (runs of several scenes then calibrate
together, each with its scene's models). Finished steps are kept (resumable). The scenes are
used as given: docs/RESULTS.md runs ``s2p heights`` on each first (the paper's baseline).
Writes OUT/r90.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seg2pose.cli.accuracy import s2p_command  # noqa: E402


def sh(*args) -> None:
    print("$ s2p " + " ".join(map(str, args)), flush=True)
    subprocess.run(s2p_command(*args), check=True)


def run_once(scene: Path, out: Path, config: str, split: str, method: list[str], smooth: int,
             r90: Path | None = None) -> Path:
    if not (out / "poses.csv").exists():
        sh("run", scene, "-o", out, "-c", config, "--split", split, *method,
           *(["--smooth", smooth] if smooth else []), *(["--r90", r90] if r90 else []),
           "--force")
    return out


def calibrate(scene: Path, runs: list[Path], path: Path) -> Path:
    if not path.exists():
        sh("calibrate-errors", scene, *[x for r in runs for x in ("--run", r)], "-o", path)
    return path


def evaluate(scene: Path, run: Path) -> dict:
    res = subprocess.run(s2p_command("eval", scene, "--run", run, "--split", "test", "--json"),
                         check=True, capture_output=True, text=True)
    return json.loads(res.stdout)


def coverage_spread(scene: Path, run: Path, draws: int = 2000) -> dict:
    """Per class, the 5 and 95 % quantiles of the test split's coverage when its road users are
    drawn again with replacement (a road user's error is nearly constant along its track, so
    the coverage of a class with a dozen road users varies by more than the 0.85-0.95 band)."""
    import numpy as np

    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import read_run
    from seg2pose.io.scene import load_scene
    from seg2pose.method.uncertainty import pose_errors

    poses = read_run(run).poses
    err = pose_errors(np.column_stack([poses.frame, poses.track_id]), poses.xyz[:, :2],
                      read_poses(load_scene(scene).gt_path))
    ok = np.isfinite(err) & np.isfinite(poses.r90)
    rng = np.random.default_rng(0)
    out = {}
    for c in np.unique(poses.cls[ok]):
        m = ok & (poses.cls == c)
        tids, inv = np.unique(poses.track_id[m], return_inverse=True)
        hit = np.bincount(inv, weights=err[m] <= poses.r90[m], minlength=len(tids))
        n = np.bincount(inv, minlength=len(tids))
        pick = rng.integers(0, len(tids), (draws, len(tids)))
        cov = hit[pick].sum(1) / n[pick].sum(1)
        out[str(c)] = {"road_users": int(len(tids)), "q05": float(np.quantile(cov, 0.05)),
                       "q95": float(np.quantile(cov, 0.95))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--tune", type=Path, action="append", default=[])
    ap.add_argument("--held", type=Path, action="append", required=True)
    ap.add_argument("--cal", action="append", choices=["tune", "own", "others", "all"])
    ap.add_argument("--configs", default="mono-1,tri-I")
    ap.add_argument("--models", type=Path, action="append")
    ap.add_argument("--scene-models", metavar="NAME")
    ap.add_argument("--smooth", type=int, default=0)
    ap.add_argument("--own-val", action="store_true")
    a = ap.parse_args()
    cal_on = a.cal or (["tune", "own"] if a.own_val else ["tune"])
    if "tune" in cal_on and not a.tune:
        ap.error("--cal tune needs --tune SCENE")
    if a.models and a.scene_models:
        ap.error("--models and --scene-models: one or the other")

    def method(scene: Path) -> list[str]:
        if a.scene_models:
            return ["--models", scene / a.scene_models]
        return [x for m in (a.models or []) for x in ("--models", m)] or ["--baseline"]

    name = a.scene_models or ("baseline" if not a.models else "s2pn")
    out = a.out
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for cfg in a.configs.split(","):
        def val(scene: Path) -> Path:
            return run_once(scene, out / f"{scene.name}-{cfg}-{name}-val", cfg, "val",
                            method(scene), a.smooth)

        def cal_from(scenes: list[Path]) -> Path:
            tag = "+".join(t.name for t in scenes)
            return calibrate(scenes[0], [val(t) for t in scenes], out / f"r90-{tag}-{cfg}-{name}.json")

        for held in a.held:
            others = [h for h in a.held if h != held]
            sources = {"tune": a.tune, "own": [held], "others": others, "all": a.held}  # one order: one file
            for which in cal_on:
                c = cal_from(sources[which])
                run = run_once(held, out / f"{held.name}-{cfg}-{name}-test-{which}", cfg, "test",
                               method(held), a.smooth, c)
                r = evaluate(held, run)["r90"]
                r["spread"] = coverage_spread(held, run)
                results[f"{held.name} {cfg} {name} {which}"] = r
    (out / "r90.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"{'run':48s} {'class':11s} {'cov':>6s} {'5-95 %':>10s} {'r90 m':>7s} {'err m':>7s} "
          f"{'ratio':>6s} {'rho':>6s}")
    for key, r in results.items():
        for cls, d in [("all", r)] + sorted(r["per_class"].items()):
            sp = r["spread"].get(cls)
            band = f"{sp['q05']:.2f}-{sp['q95']:.2f}" if sp else ""
            print(f"{key:48s} {cls:11s} {d['coverage']:6.3f} {band:>10s} {d['mean_r90']:7.3f} "
                  f"{d['mean_error']:7.3f} {d['sharpness']:6.2f} {d['spearman']:6.2f}")


if __name__ == "__main__":
    main()
