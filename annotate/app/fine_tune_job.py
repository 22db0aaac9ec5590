"""The app's "what next" and "train now": the scene-wide queue of road users to annotate
(``annotate.suggest``, key ``u``) and a background fine-tuning of the run's models on the
annotations so far (key ``Shift+u``), with its progress in the panel.

Train now exports the annotations to the scene's ``gt/poses.csv`` (``annotate.export``: an
export of the annotation replaces an earlier export, never other truth) and starts
``s2p train SCENE --from START -o SCENE/models-fine-tuned`` as a child process; START is the
folder of the models the app's run was made with (run.json). The job's last line, stage and
time are the panel's ``train_job``; when it ends, the panel says where the models are and the
``s2p run`` that shows their estimates (and error bars, with an ``s2p calibrate-errors`` of its
own) in the app. Functions of the controller (``ctl``), called by ``Actions`` and
``PanelData``; the job and the queue's cache live on the controller as ``_fine_tune_job`` and
``_queue_cache``.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from annotate.model import EditError

OUT_NAME = "models-fine-tuned"  # SCENE/<this>: where train now writes


@dataclass
class TrainJob:
    """One background ``s2p train --from``: its state ("running", "done", "failed"), the last
    line it said, when it started and ended, the models it writes."""

    command: list[str]
    models: Path
    state: str = "running"
    line: str = ""
    started: float = field(default_factory=time.time)
    ended: float | None = None
    models_done: int = 0
    proc: subprocess.Popen | None = None

    def start(self) -> TrainJob:
        self.proc = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, bufsize=1)
        threading.Thread(target=self._follow, daemon=True).start()
        return self

    def _follow(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for raw in self.proc.stdout:
            for part in raw.replace("\r", "\n").splitlines():
                if part.strip():
                    self.line = part.strip()[:200]
                    if any(k in part for k in (": fine-tuned,", ": kept its start", "no epoch beat", " chosen (")):
                        self.models_done += 1
        rc = self.proc.wait()
        self.state = "done" if rc == 0 else "failed"
        self.ended = time.time()

    def status(self) -> dict:
        t = (self.ended or time.time()) - self.started
        out = {"state": self.state, "line": self.line, "seconds": round(t), "models_done": self.models_done,
               "models": str(self.models)}
        if self.state == "done":
            out["next"] = (f"s2p run SCENE --models {self.models} -o RUN, then open the app with "
                           "--run RUN to see the new estimates")
        return out


def _start_models(ctl) -> Path:
    """The folder of the models the app's run used (run.json), the start of a fine-tuning."""
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
    return (run.path / paths[0]).resolve().parent


def train_now(ctl) -> str:
    """Export the annotations and start the background fine-tuning (one at a time)."""
    from annotate.export import export_gt

    job = getattr(ctl, "_fine_tune_job", None)
    if job is not None and job.state == "running":
        return f"a fine-tuning is running already ({job.status()['seconds']} s): {job.line}"
    start = _start_models(ctl)
    scene = ctl.project.scene
    out = scene.root / OUT_NAME
    if out.resolve() == start:
        raise EditError(f"the run's models are {out}, where train now writes; run the app on a run "
                        "of the start models")
    path = export_gt(ctl.project)
    cmd = [sys.executable, "-c", "from seg2pose.cli import main; main()", "train", str(scene.root),
           "--from", str(start), "-o", str(out)]
    ctl._fine_tune_job = TrainJob(cmd, out).start()
    return f"exported {path.name}; fine-tuning {start.name} in the background into {out.name}"


def job_status(ctl) -> dict | None:
    """The panel's ``train_job``: None before the first train now."""
    job = getattr(ctl, "_fine_tune_job", None)
    return None if job is None else job.status()


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
