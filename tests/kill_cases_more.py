"""More writers for benches/bench_faults.py (issue 38): ``review -o`` (a recording), ``screenshot``
(the headless viewer it starts: no viewer process and no /tmp/s2p-viewer-state-* folder may
outlive a kill), ``calibrate-errors``, ``conflicts`` (CSV, PET-only CSV and conflict map as one command's
outputs) and ``calibrate-camera --points`` (calib.json and the files beside it as a set). What
is compared where the bytes differ from run to run (a recording's id): what a reader sees."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from kill_harness import Case, snapshot


def _recording_state(path: Path) -> Callable:
    """An .rrd as a reader sees it: None when absent, else (complete: Rerun's footer is there,
    rows per entity). A recording's id and times differ between runs, its rows do not."""
    def state(case):
        if not path.exists():
            return [None]
        from rerun_bindings import check_for_rrd_footer
        from review_fixtures import rrd_rows

        try:
            footer = bool(check_for_rrd_footer(str(path)))
            rows = sorted(rrd_rows(path)[0].items())
        except Exception as e:  # noqa: BLE001 - a recording that does not read is a broken output
            return [f"does not read: {type(e).__name__}"]
        return [(footer, rows)]
    return state


def _png_state(path: Path) -> Callable:
    """A PNG as a reader sees it: None when absent, else its pixel size when it decodes whole
    (the headless viewer's rendering need not be byte for byte the same each time)."""
    def state(case):
        if not path.exists():
            return [None]
        import cv2

        data = path.read_bytes()
        im = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        whole = data.endswith(b"IEND\xaeB`\x82")
        return [("png", im.shape[:2]) if im is not None and whole else "broken"]
    return state


def viewer_states(case: Case, wait: float = 15.0) -> list[Path]:
    """What the headless viewers ``case``'s command started left in its own TMPDIR (their state
    folders, Rerun's data folders, the runtime folder made for them), once their guards (which
    clean up a moment after the command ends) have had up to ``wait`` seconds."""
    import time

    end = time.monotonic() + wait
    while True:
        left = sorted(p for g in ("s2p-viewer-state-*", "rerun-data-*", "s2p-xdg-*")
                      for p in Path(case.env["TMPDIR"]).glob(g)) if case.env else []
        if not left or time.monotonic() > end:
            return left
        time.sleep(0.2)


def build_more_cases(root: Path) -> list[Case]:
    """The writers above on small inputs under ``root``, each with an old output to replace."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import cv2
    from hostile_fixtures import write_scene
    from scene_fixtures import make_tiny_scene

    from seg2pose.io.atomic import atomic_write_bytes
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.method.r90_calibrate import calibrate_run

    root.mkdir(parents=True, exist_ok=True)
    old, out = root / "old", root / "out"
    old.mkdir()
    out.mkdir()
    # review -o and screenshot: a scene, its run, and a recording of another scene
    scene = write_scene(root / "scene", frames=12, users=4)
    other = write_scene(root / "other", frames=5, users=2)
    run_scene(scene, root / "run", RunOptions(baseline=True, progress=False))
    run_scene(other, root / "other-run", RunOptions(baseline=True, progress=False))
    from s2p_review.session import RecordOptions, Targets, record

    record(other, [root / "other-run"], Targets(rrd=old / "r.rrd"), RecordOptions())
    record(scene, [root / "run"], Targets(rrd=root / "shot.rrd"), RecordOptions())
    atomic_write_bytes(old / "shot.png", cv2.imencode(".png", np.full((12, 16, 3), 90, np.uint8))[1].tobytes())
    # calibrate-errors: a validation run of a tiny scene; the old fit from another scene
    tiny = make_tiny_scene(root / "tiny", frames=20, n_users=4)
    run_scene(tiny, root / "val", RunOptions(baseline=True, split="val", progress=False))
    tiny2 = make_tiny_scene(root / "tiny2", frames=20, n_users=4, seed=1)
    run_scene(tiny2, root / "val2", RunOptions(baseline=True, split="val", progress=False))
    calibrate_run(tiny2, root / "val2", old / "r90.json")
    # conflicts: the run's poses; the old CSVs from the other run
    from seg2pose.cli import main

    def cli(*argv) -> None:
        try:
            main([str(a) for a in argv])
        except SystemExit as e:
            assert not e.code, argv
    cli("conflicts", root / "other-run", "-o", old / "c.csv", "--pet-only", old / "pet.csv", "--map",
        old / "map.png", "--draws", "20")
    # calibrate-camera --points: eight pairs; the old set from six of them
    from video_fixtures import H, W, write_folder

    from seg2pose.geometry.camera import Camera

    cam = Camera.look_at("c0", np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 150.0, W, H)
    write_folder(root / "frames", 2, [])
    grid = np.array([[x, y, 0.0] for y in (0.5, 4.0, 9.0, 18.0) for x in (-3.0, 3.0)])
    uv = cam.project_points(grid)[0]
    rows = [f"c0,{u!r},{v!r},{x},{y},0" for (u, v), (x, y, _) in zip(uv.tolist(), grid.tolist(), strict=True)]
    (root / "pairs.csv").write_text("camera,u,v,x,y,z\n" + "\n".join(rows) + "\n")
    (root / "pairs6.csv").write_text("camera,u,v,x,y,z\n" + "\n".join(rows[:6]) + "\n")
    (old / "cal").mkdir()
    cli("calibrate-camera", root / "frames", "--points", root / "pairs6.csv", "-o", old / "cal" / "calib.json")
    cal_names = ["calib.json", "calib.ground.csv", "calib.report.txt", "calib.c0.png"]
    (out / "cal").mkdir()
    tmp = root / "tmp"  # the screenshot's TMPDIR: its viewers' state folders go there
    tmp.mkdir()
    return [
        Case("review-o", ["review", scene.root, "--run", root / "run", "-o", out / "r.rrd", "--force"],
             [out / "r.rrd"], [old / "r.rrd"], state=_recording_state(out / "r.rrd")),
        Case("screenshot", ["screenshot", root / "shot.rrd", "-o", out / "shot.png", "--frame", "6", "--force"],
             [out / "shot.png"], [old / "shot.png"], state=_png_state(out / "shot.png"), tree=True,
             env={"TMPDIR": str(tmp)}),
        Case("calibrate-errors", ["calibrate-errors", tiny.root, "--run", root / "val", "-o", out / "r90.json",
                                  "--force"], [out / "r90.json"], [old / "r90.json"]),
        Case("conflicts", ["conflicts", root / "run", "-o", out / "c.csv", "--pet-only", out / "pet.csv",
                           "--map", out / "map.png", "--draws", "20", "--force"],
             [out / "c.csv", out / "pet.csv", out / "map.png"], [old / "c.csv", old / "pet.csv", old / "map.png"]),
        Case("calibrate-camera", ["calibrate-camera", root / "frames", "--points", root / "pairs.csv", "-o",
                                  out / "cal" / "calib.json", "--force"],
             [out / "cal" / n for n in cal_names], [old / "cal" / n for n in cal_names]),
    ]


__all__ = ["build_more_cases", "snapshot", "viewer_states"]
