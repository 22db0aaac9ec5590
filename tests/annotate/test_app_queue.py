"""The app's scene-wide queue (key u) and its background "train now" (Shift+u,
annotate/app/fine_tune_job.py): the panel shows the queue of annotate.suggest, u goes to the
first suggested frame, train now refuses a baseline run in one line, and the job's progress
is read from the child's lines."""

from __future__ import annotations

import sys
import time

import pytest

from annotate.app.controller import Controller
from annotate.app.fine_tune_job import Step, TrainJob


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
            "print('all__car: fine-tuned chosen (car: fine-tuned (2 road user(s): ...))'); "
            "print('all__bicyclist: kept its start model (no annotated bicyclist masks)'); "
            "print('  all__car: fine-tuned chosen (car: fine-tuned (2 road user(s): ...))'); print('models in X')")
    st = _wait(TrainJob([Step("train", [sys.executable, "-c", said])], tmp_path / "m").start())
    assert st["state"] == "done" and st["models_done"] == 2 and st["line"] == "models in X"
    assert "s2p run SCENE --models" in st["next"] and st["stage"] == "train"
    st = _wait(TrainJob([Step("train", [sys.executable, "-c", "import sys; print('error: no'); sys.exit(2)"])],
                        tmp_path / "m").start())
    assert st["state"] == "failed" and st["line"] == "error: no" and "next" not in st


def test_train_job_steps_run_in_order_an_optional_one_may_fail(tmp_path):
    """Steps one after another; an optional step's failure is noted and the job goes on, a
    required one's ends it there (the later steps never start)."""
    log = tmp_path / "log.txt"

    def step(name, code, optional=False):
        py = (f"import sys; open({str(log)!r}, 'a').write({name!r} + ' '); print({name!r} + ' said'); "
              f"sys.exit({code})")
        return Step(name, [sys.executable, "-c", py], optional)

    st = _wait(TrainJob([step("train", 0), step("run", 0), step("error bars", 1, True),
                         step("run with error bars", 0)], tmp_path / "m", tmp_path / "r").start())
    assert st["state"] == "done" and st["stage"] == "run with error bars"
    assert st["skipped"] == ["error bars: error bars said"]
    assert log.read_text() == "train run error bars run with error bars "
    log.unlink()
    st = _wait(TrainJob([step("train", 3), step("run", 0)], tmp_path / "m", tmp_path / "r").start())
    assert st["state"] == "failed" and st["stage"] == "train" and log.read_text() == "train "


def test_a_finished_job_s_run_is_loaded_into_the_app_once(scene_run, tmp_path):
    """The panel after a job that made a run: the project's estimates come from that run, the
    viewer's ``on_run`` hears of it once; a second train now from a run of the fine-tuned
    models starts from the start those models record."""
    import json
    import shutil

    from annotate.app.fine_tune_job import OUT_NAME, _start_models

    root, run = scene_run
    other = tmp_path / "run2"
    shutil.copytree(run, other)
    ctl = Controller.open(root, run=run, cameras=["c1"])
    heard = []
    ctl.on_run.append(heard.append)
    try:
        ctl._fine_tune_job = TrainJob([], root / OUT_NAME, other, state="done", ended=time.time())
        st = ctl.panel()["train_job"]
        assert st["run"] == str(other) and heard == [other]
        assert ctl.project._run.path.resolve() == other.resolve()
        ctl.panel()
        assert heard == [other]  # once
        # a run of train now's own folder: the start comes from the models' record
        out = root / OUT_NAME
        out.mkdir()
        start = tmp_path / "start"
        record = {"fine_tune": {"start": {"file": str(start / "all__car.safetensors")}}}
        (out / "all__car.json").write_text(json.dumps(record))
        meta = json.loads((other / "run.json").read_text())
        meta["models"] = {"c1/car": {"path": str(out / "all__car.safetensors")}}
        (other / "run.json").write_text(json.dumps(meta))
        assert _start_models(ctl) == start.resolve()
    finally:
        ctl.close()
