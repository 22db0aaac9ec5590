"""Zero-annotation Seg2PoseNet on background-subtraction masks (issue 13): baseline vs network.

    PYTHONPATH=. .venv/bin/python benches/video_zero.py VIDEO_SCENE --out DIR [--variant NAME ...]
        [--truth TRUTH_SCENE] [--train-arg=--epochs=10 ...]

VIDEO_SCENE: ``s2p synth -o OUT --frames 200 --video --seed S``. Every step is a real ``s2p``
command (printed, with its wall time), in a fresh copy of the scene (DIR/bg-S):

1. ``s2p masks-from-video`` (MOG2 + components + tracker + size classes) on camera c1;
2. ``base-default``: ``s2p run --baseline -c mono-1`` with the scene's default heights;
3. ``s2p heights --rough 2000 --camera c1`` (no annotations: rough models rendered clean, which
   give the filmed ones' heights within 1.2 cm, docs/RESULTS.md), then ``base-rough``: the baseline with those heights;
4. per variant: ``s2p train --protocol quick --zero-annotation --camera c1`` (+ the variant's
   flags), ``s2p run -c mono-1 --models``; variants: ``zero-clean`` (``--no-rough-video``, the
   default: clean rough silhouettes, radial calibration), ``zero-video`` (``--rough-video``:
   rough models filmed over the video's background and background-subtracted, no radial
   calibration);
5. ``s2p eval --match nearest`` for every run (all frames), and with ``--truth`` the same
   runs on the truth masks (rendered silhouettes of every visible road user, ids = truth ids)
   for the error budget: ``truth-base`` (rough heights) and ``truth-<variant>``;
6. with ``--smooth N``: base-rough and every variant again with ``s2p run --smooth N`` (positions
   smoothed along the tracks, the baseline's too, so the comparison stays fair).

Prints one JSON line per run and writes DIR/video_zero-S.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from video_figures import fresh_scene  # noqa: E402

VARIANTS = {"zero-video": ["--rough-video"], "zero-clean": ["--no-rough-video"]}


def s2p(*args: str) -> str:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from seg2pose.cli import main; main()", *args],
                       capture_output=True, text=True)
    print(f"$ s2p {' '.join(args)}   [{time.perf_counter() - t:.0f} s]", file=sys.stderr, flush=True)
    if r.returncode:
        raise SystemExit(f"s2p {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")
    return r.stdout + r.stderr


def ev_row(name: str, scene: Path, run: Path, match: str = "nearest") -> dict:
    out = s2p("eval", str(scene), "--run", str(run), "--match", match, "--json")
    ev = json.loads(out[out.index("{"):out.rindex("}") + 1])
    row = {"run": name, "mean_m": ev["mean_error"], "median_m": ev["median_error"],
           "matched": f"{ev['n_matched']}/{ev['n_gt']}", "per_class": ev["per_class"]}
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("video_scene", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--truth", type=Path, help="the same seed with --no-detector-noise --match all")
    ap.add_argument("--variant", action="append", choices=sorted(VARIANTS))
    ap.add_argument("--train-arg", action="append", default=[], help="extra s2p train argument")
    ap.add_argument("--run-arg", action="append", default=[], help="extra s2p run argument (network runs)")
    ap.add_argument("--tag", default="", help="suffix of the variants' model and run names")
    ap.add_argument("--rough-heights", type=int, default=2000)
    ap.add_argument("--smooth", type=int, default=0,
                    help="also base-rough and every variant with positions smoothed along the tracks "
                         "over this many frames either side (rows named ...-smooth<N>)")
    a = ap.parse_args()
    seed = json.loads((a.video_scene / "scene.json").read_text())["extra"]["generator"]["seed"]
    sc = a.out / f"bg-{seed}"
    res_path = a.out / f"video_zero-{seed}.json"
    # finished steps are kept (the script resumes; new variants add rows)
    rows = json.loads(res_path.read_text()) if res_path.exists() else {}

    def save(row: dict) -> None:
        rows[row["run"]] = row
        res_path.write_text(json.dumps(rows, indent=1))

    if not (sc / "masks" / "c1.txt").exists():
        fresh_scene(a.video_scene, sc)
        print(s2p("masks-from-video", str(sc), "--camera", "c1", "--no-progress"), file=sys.stderr)
    if "base-rough" not in rows:
        s2p("run", str(sc), "-o", str(sc / "out" / "base-default"), "-c", "mono-1", "--baseline", "--force")
        save(ev_row("base-default", sc, sc / "out" / "base-default"))
        print(s2p("heights", str(sc), "--rough", str(a.rough_heights), "--camera", "c1"), file=sys.stderr)
        s2p("run", str(sc), "-o", str(sc / "out" / "base-rough"), "-c", "mono-1", "--baseline", "--force")
        save(ev_row("base-rough", sc, sc / "out" / "base-rough"))
    sm = f"-smooth{a.smooth}"
    if a.smooth and f"base-rough{sm}" not in rows:
        s2p("run", str(sc), "-o", str(sc / "out" / f"base-rough{sm}"), "-c", "mono-1", "--baseline",
            "--smooth", str(a.smooth), "--force")
        save(ev_row(f"base-rough{sm}", sc, sc / "out" / f"base-rough{sm}"))
    tr = None
    if a.truth:
        # the truth masks in a scene with the same (rough) heights
        tr = a.out / f"truth-{seed}"
        if "truth-base-rough" not in rows:
            if tr.exists():
                shutil.rmtree(tr)
            shutil.copytree(a.truth, tr, ignore=shutil.ignore_patterns("video", "models", "out"))
            shutil.copy2(sc / "scene.json", tr / "scene.json")
            s2p("run", str(tr), "-o", str(tr / "out" / "base-rough"), "-c", "mono-1", "--baseline", "--force")
            save(ev_row("truth-base-rough", tr, tr / "out" / "base-rough", "ids"))
    for v in a.variant or ["zero-video"]:
        name = v + a.tag
        models = sc / f"models-{name}"
        # s2p train skips finished models and resumes interrupted ones
        t = time.perf_counter()
        log = s2p("train", str(sc), "--protocol", "quick", "--zero-annotation", "--camera", "c1",
                  "-o", str(models), "--threads", "1", *VARIANTS[v], *a.train_arg)
        wall = time.perf_counter() - t
        (a.out / f"train-{name}-{seed}.log").write_text(log)
        s2p("run", str(sc), "-o", str(sc / "out" / name), "-c", "mono-1", "--models", str(models),
            "--force", *a.run_arg)
        row = ev_row(name, sc, sc / "out" / name)
        row["train_wall_s"] = round(wall)
        row["train_args"] = VARIANTS[v] + a.train_arg
        row["far_residuals"] = json.loads((sc / "out" / name / "run.json").read_text()).get("far_residuals")
        save(row)
        if a.smooth and name + sm not in rows:
            s2p("run", str(sc), "-o", str(sc / "out" / (name + sm)), "-c", "mono-1", "--models", str(models),
                "--smooth", str(a.smooth), "--force", *a.run_arg)
            save(ev_row(name + sm, sc, sc / "out" / (name + sm)))
        if tr is not None:
            s2p("run", str(tr), "-o", str(tr / "out" / name), "-c", "mono-1", "--models", str(models),
                "--force", *a.run_arg)
            save(ev_row(f"truth-{name}", tr, tr / "out" / name, "ids"))


if __name__ == "__main__":
    main()
