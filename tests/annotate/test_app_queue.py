"""The app's scene-wide queue (key u) and its background "train now" (Shift+u,
annotate/app/fine_tune_job.py): the panel shows the queue of annotate.suggest, u goes to the
first suggested frame, train now refuses a baseline run in one line, and the job's progress
is read from the child's lines."""

from __future__ import annotations

import sys
import time

import pytest

from annotate.app.controller import Controller
from annotate.app.fine_tune_job import TrainJob


@pytest.fixture(scope="module")
def scene_run(tmp_path_factory):
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("queue") / "scene"
    generate_scene(root, SynthOptions(preset="small", frames=12, seed=2, video=False, progress=False,
                                      workers=1))
    run = root.parent / "run"
    run_scene(load_scene(root), run, RunOptions(config="mono-1", baseline=True, progress=False))
    return root, run


def test_queue_in_the_panel_and_u_goes_to_its_first_frame(scene_run):
    from annotate.suggest import project_queue

    root, run = scene_run
    ctl = Controller.open(root, run=run, cameras=["c1"])
    try:
        rows = ctl.panel()["queue"]
        want = project_queue(ctl.project, limit=10)
        assert rows and [r["track"] for r in rows] == [c.track for c in want]
        test = ctl.project.scene.split_range("test")
        assert all(not test[0] <= f <= test[1] for r in rows for f in r["frames"])
        msg = ctl.do("next_queued")
        assert msg.startswith(f"next to annotate: the run's track {rows[0]['track']}")
        assert ctl.frame == rows[0]["frames"][0]
        # a baseline run has no models to start from: one line, nothing started
        msg = ctl.do("train_now")
        assert "is a baseline run (no models)" in msg and ctl.panel()["train_job"] is None
    finally:
        ctl.close()


def _wait(job: TrainJob) -> dict:
    for _ in range(200):
        if job.state != "running":
            break
        time.sleep(0.05)
    return job.status()


def test_train_job_progress_from_the_childs_lines(tmp_path):
    said = ("import sys; print('all__car: fine-tuning on 10 annotated examples', file=sys.stderr); "
            "print('all__car: fine-tuned, epoch 2 of 4 run; held-out error 0.5 -> 0.4 m'); "
            "print('all__bicyclist: kept its start model (no annotated bicyclist masks)'); print('models in X')")
    st = _wait(TrainJob([sys.executable, "-c", said], tmp_path / "m").start())
    assert st["state"] == "done" and st["models_done"] == 2 and st["line"] == "models in X"
    assert "s2p run SCENE --models" in st["next"]
    st = _wait(TrainJob([sys.executable, "-c", "import sys; print('error: no'); sys.exit(2)"],
                        tmp_path / "m").start())
    assert st["state"] == "failed" and st["line"] == "error: no" and "next" not in st
