"""How good the error bars r90_m are on held-out scenes (issue 25): calibrated on the val split
of one or more tuning scenes, applied to the test split of held-out scenes, scored per class
(coverage, mean r90_m / mean error, Spearman of r90_m with the error).

    .venv/bin/python benches/r90_coverage.py OUT --tune SCENE [--tune SCENE ...]
        --held SCENE [--held SCENE ...] [--configs mono-1,tri-I] [--models DIR [--models DIR ...]]
        [--smooth N] [--own-val]

Per configuration, every step is the ``s2p`` command a user types (printed as it runs):
``s2p run --split val`` on each tuning scene, one ``s2p calibrate`` on all those runs, then
``s2p run --split test --r90`` and ``s2p eval --json`` on each held-out scene. Without ``--models`` the runs are the
baseline; ``--models`` repeated gives an ensemble (its spread is a cue). ``--own-val``: also
calibrate on each held-out scene's own val split. Finished steps are kept (resumable). The
scenes are used as given: docs/RESULTS.md runs ``s2p heights`` on each first (the paper's
baseline).
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
        sh("calibrate", scene, *[x for r in runs for x in ("--run", r)], "-o", path)
    return path


def evaluate(scene: Path, run: Path) -> dict:
    res = subprocess.run(s2p_command("eval", scene, "--run", run, "--split", "test", "--json"),
                         check=True, capture_output=True, text=True)
    return json.loads(res.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--tune", type=Path, action="append", required=True)
    ap.add_argument("--held", type=Path, action="append", required=True)
    ap.add_argument("--configs", default="mono-1,tri-I")
    ap.add_argument("--models", type=Path, action="append")
    ap.add_argument("--smooth", type=int, default=0)
    ap.add_argument("--own-val", action="store_true")
    a = ap.parse_args()
    method = [x for m in (a.models or []) for x in ("--models", m)] or ["--baseline"]
    name = "baseline" if not a.models else "s2pn"
    out = a.out
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for cfg in a.configs.split(","):
        vals = [run_once(t, out / f"{t.name}-{cfg}-{name}-val", cfg, "val", method, a.smooth)
                for t in a.tune]
        tag = "+".join(t.name for t in a.tune)
        cal = calibrate(a.tune[0], vals, out / f"r90-{tag}-{cfg}-{name}.json")
        for held in a.held:
            cals = {"tune": cal}
            if a.own_val:
                hv = run_once(held, out / f"{held.name}-{cfg}-{name}-val", cfg, "val", method, a.smooth)
                cals["own"] = calibrate(held, [hv], out / f"r90-{held.name}-{cfg}-{name}.json")
            for which, c in cals.items():
                run = run_once(held, out / f"{held.name}-{cfg}-{name}-test-{which}", cfg, "test",
                               method, a.smooth, c)
                results[f"{held.name} {cfg} {name} {which}"] = evaluate(held, run)["r90"]
    (out / "r90.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"{'run':44s} {'class':11s} {'cov':>6s} {'r90 m':>7s} {'err m':>7s} {'ratio':>6s} {'rho':>6s}")
    for key, r in results.items():
        for cls, d in [("all", r)] + sorted(r["per_class"].items()):
            print(f"{key:44s} {cls:11s} {d['coverage']:6.3f} {d['mean_r90']:7.3f} "
                  f"{d['mean_error']:7.3f} {d['sharpness']:6.2f} {d['spearman']:6.2f}")


if __name__ == "__main__":
    main()
