"""The app's "what next" and "train now": the scene-wide queue of road users to annotate
(``annotate.suggest``, key ``u``) and a background fine-tuning of the run's models on the
annotations so far (key ``Shift+u``), with its progress in the panel.

Train now exports the annotations to the scene's ``gt/poses.csv`` (``annotate.export``: an
export of the annotation replaces an earlier export, never other truth) and runs, as child
processes one after another (``TrainJob``):

1. ``s2p train SCENE --from START -o SCENE/models-fine-tuned`` (START: the folder of the models
   the app's run was made with, run.json; when that run is already of the fine-tuned models,
   the start they were fine-tuned from, so that a second train now starts afresh);
2. ``s2p run SCENE --models SCENE/models-fine-tuned -o SCENE/runs/fine-tuned`` (the app's
   run's cameras and split);
3. ``s2p calibrate-errors SCENE --run ...`` into the models' ``r90.json`` (the error bars
   refitted against the annotations: their road users are also what the models were tuned
   on, so the bars are on the short side; a fit that cannot be made leaves the run without
   them, said in the panel);
4. ``s2p run`` again, so that the run carries the refitted ``r90_m``.

The job's stage, last line and time are the panel's ``train_job``; when it has finished, the
next panel update loads the new run into the app (estimates, queue, suggestions) and the
viewer logs it (``on_run``). Functions of the controller (``ctl``), called by ``Actions`` and
``PanelData``; the job and the queue's cache live on the controller as ``_fine_tune_job``
and ``_queue_cache``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from annotate.model import EditError

OUT_NAME = "models-fine-tuned"  # SCENE/<this>: where train now writes
RUN_NAME = "fine-tuned"         # SCENE/runs/<this>: the run of the fine-tuned models
MODEL_DONE = (": fine-tuned,", ": kept its start", "no epoch beat", " chosen (")


@dataclass
class Step:
    """One child process of the job: its name (the panel's stage), command, and whether the
    job goes on without it when it fails (the error bars' fit)."""

    name: str
    command: list[str]
    optional: bool = False


@dataclass
class TrainJob:
    """The background steps of train now (see the module docstring): the state ("running",
    "done", "failed"), the stage, the last line said, when it started and ended, the models it
    writes, the run it makes (None: no run step), what was skipped."""

    steps: list[Step]
    models: Path
    run: Path | None = None
    state: str = "running"
    stage: str = ""
    line: str = ""
    started: float = field(default_factory=time.time)
    ended: float | None = None
    models_done: int = 0
    done_names: set = field(default_factory=set)  # the models said finished (each once)
    skipped: list[str] = field(default_factory=list)
    applied: bool = False  # the new run loaded into the app
    proc: subprocess.Popen | None = None

    def start(self) -> TrainJob:
        threading.Thread(target=self._work, daemon=True).start()
        return self

    def _work(self) -> None:
        ok = True
        for step in self.steps:
            self.stage = step.name
            if self._step(step) == 0:
                continue
            if step.optional:
                self.skipped.append(f"{step.name}: {self.line}")
                continue
            ok = False
            break
        self.state = "done" if ok else "failed"
        self.ended = time.time()

    def _step(self, step: Step) -> int:
        self.proc = subprocess.Popen(step.command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, bufsize=1)
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            for part in raw.replace("\r", "\n").splitlines():
                if part.strip():
                    self.line = part.strip()[:200]
                    if step.name == "train" and any(k in part for k in MODEL_DONE):
                        # the command repeats its lines at the end: each model counts once
                        self.done_names.add(part.strip().split(":")[0])
                        self.models_done = len(self.done_names)
        return self.proc.wait()

    def status(self) -> dict:
        t = (self.ended or time.time()) - self.started
        out = {"state": self.state, "stage": self.stage, "line": self.line, "seconds": round(t),
               "models_done": self.models_done, "models": str(self.models)}
        if self.skipped:
            out["skipped"] = list(self.skipped)
        if self.state == "done":
            out["run"] = str(self.run) if self.run is not None else None
            out["next"] = ("the app shows the fine-tuned models' run" if self.run is not None else
                           f"s2p run SCENE --models {self.models} -o RUN, then open the app with "
                           "--run RUN to see the new estimates")
        return out


def _start_models(ctl) -> Path:
    """The folder of the models the app's run used (run.json), the start of a fine-tuning; a
    folder train now made itself gives the start its models were fine-tuned from."""
    from seg2pose.io.run import read_run_meta

    run = getattr(ctl.project, "_run", None)
    if run is None:
        raise EditError("train now needs a run of the models to start from: open the app with --run")
    meta = read_run_meta(run.path)
    paths = [m.get("path") for m in (meta.get("models") or {}).values()]
    paths = [p[0] if isinstance(p, list) else p for p in paths if p]
    if not paths:
        raise EditError(f"{run.path} is a baseline run (no models); fine-tuning needs a run of "
                        "Seg2PoseNet models (e.g. the shipped demo models or a zero-annotation run)")
    folder = (run.path / paths[0]).resolve().parent
    if folder == (ctl.project.scene.root / OUT_NAME).resolve():
        for side in sorted(folder.glob("*__*.json")):
            start = (json.loads(side.read_text()).get("fine_tune") or {}).get("start") or {}
            if start.get("file"):
                return Path(start["file"]).resolve().parent
        raise EditError(f"the run's models are {folder}, where train now writes, and they do not "
                        "say which start they came from; run the app on a run of the start models")
    return folder


def _run_args(ctl) -> list[str]:
    """The app's run's camera configuration and split, as ``s2p run`` options."""
    from seg2pose.io.run import read_run_meta

    meta = read_run_meta(ctl.project._run.path)
    out = ["-c", str(meta["config"])] if meta.get("config") else []
    return out + (["--split", str(meta["split"])] if meta.get("split") else [])


def train_now(ctl) -> str:
    """Export the annotations and start the background steps (one job at a time)."""
    from annotate.export import export_gt

    job = getattr(ctl, "_fine_tune_job", None)
    if job is not None and job.state == "running":
        return f"a fine-tuning is running already ({job.status()['seconds']} s): {job.line}"
    start = _start_models(ctl)
    scene = ctl.project.scene
    out, run = scene.root / OUT_NAME, scene.root / "runs" / RUN_NAME
    path = export_gt(ctl.project)
    s2p = [sys.executable, "-c", "from seg2pose.cli import main; main()"]
    run_cmd = [*s2p, "run", str(scene.root), "--models", str(out), "-o", str(run), "--force",
               "--missing", "baseline", *_run_args(ctl)]
    steps = [Step("train", [*s2p, "train", str(scene.root), "--from", str(start), "-o", str(out)]),
             Step("run", run_cmd),
             Step("error bars", [*s2p, "calibrate-errors", str(scene.root), "--run", str(run),
                                 "-o", str(out / "r90.json"), "--force"], optional=True),
             Step("run with error bars", run_cmd)]
    ctl._fine_tune_job = TrainJob(steps, out, run).start()
    return (f"exported {path.name}; fine-tuning {start.name} in the background into {out.name}, "
            f"then its run {run.relative_to(scene.root)}")


def use_run(ctl, run: Path) -> None:
    """Load ``run`` into the app (estimates, queue, suggestions) and tell the viewer (``on_run``)."""
    ctl.project.load_run(run)
    ctl._run = run
    for cb in list(getattr(ctl, "on_run", [])):
        cb(run)


def job_status(ctl) -> dict | None:
    """The panel's ``train_job``: None before the first train now. A job that has finished
    with a run has it loaded into the app here, once (on the panel's thread)."""
    job = getattr(ctl, "_fine_tune_job", None)
    if job is None:
        return None
    if job.state == "done" and job.run is not None and not job.applied:
        job.applied = True
        use_run(ctl, job.run)
        ctl.message = f"the fine-tuned models' run {job.run.name} is loaded"
    return job.status()


def queue(ctl) -> list:
    """The scene-wide queue (``annotate.suggest.project_queue``), cached per journal record."""
    from annotate.suggest import project_queue

    key = (ctl.project.seq, id(getattr(ctl.project, "_run", None)))
    cache = getattr(ctl, "_queue_cache", None)
    if cache is None or cache[0] != key:
        ctl._queue_cache = cache = (key, project_queue(ctl.project, limit=10))
    return cache[1]


def queue_rows(ctl) -> list[dict]:
    """The panel's ``queue``: the next road users to annotate, best first."""
    return [{"track": c.track, "cls": c.cls, "frames": list(c.frames), "gain": round(c.gain, 2),
             "why": c.why} for c in queue(ctl)]


def next_queued(ctl) -> str:
    """Go to the first frame of the best road user in the queue (the run's track: click it
    there, then at the other suggested frames)."""
    q = queue(ctl)
    if not q:
        return ("nothing queued: the queue needs a run (--run) with views.csv, and road users "
                "not annotated yet")
    c = q[0]
    ctl.goto(c.frames[0])
    return (f"next to annotate: the run's track {c.track} ({c.why}); keyframes at frames "
            f"{', '.join(map(str, c.frames))}")
