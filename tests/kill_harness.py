"""Kill s2p commands at random moments and classify what they leave under the output's name:
``absent``, ``old`` (the complete previous output), ``new`` (the complete new one) or
``mixed`` (anything else: a partial or merged output). Used by tests/system/test_kill.py (a few kills)
and benches/bench_faults.py (many)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
S2P = [sys.executable, "-c", "from seg2pose.cli import main; main()"]


def snapshot(path: Path) -> dict | None:
    """The content of an output: None when absent; {relative path: bytes} of its files
    (a file output: {'': bytes}). run.json's creation time is left out (it differs between
    two runs of the same command). Hidden siblings are not part of it."""
    if not path.exists():
        return None
    if path.is_file():
        return {"": path.read_bytes()}
    out = {}
    for p in sorted(path.rglob("*")):
        if p.is_file():
            data = p.read_bytes()
            if p.name == "run.json":
                d = json.loads(data)
                d.pop("created", None)
                data = json.dumps(d, sort_keys=True).encode()
            out[str(p.relative_to(path))] = data
    return out


def classify(state: dict | None, old: dict | None, new: dict) -> str:
    if state is None:
        return "absent"
    if state == new:
        return "new"
    if state == old:
        return "old"
    return "mixed"


@dataclass
class Case:
    """One command: ``argv`` writes ``out`` (with --force); ``old`` is the complete output it
    replaces (a folder or file to copy into place before every kill)."""

    name: str
    argv: list
    out: Path
    old: Path
    new: dict | None = None
    seconds: float = 1.0
    counts: dict = field(default_factory=lambda: {"absent": 0, "old": 0, "new": 0, "mixed": 0})

    def put_old(self) -> None:
        if self.out.is_dir() and not self.out.is_symlink():
            shutil.rmtree(self.out)
        elif self.out.exists():
            self.out.unlink()
        if self.old.is_dir():
            shutil.copytree(self.old, self.out)
        else:
            shutil.copy2(self.old, self.out)

    def run_fully(self) -> None:
        """Run to the end once: the reference new output and the command's duration."""
        self.finish(self.start())

    def start(self) -> tuple[subprocess.Popen, float]:
        """Put the old output in place and start the command (``finish`` waits for it)."""
        self.put_old()
        p = subprocess.Popen(S2P + [str(a) for a in self.argv], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True, env=ENV)
        return p, time.perf_counter()

    def finish(self, started: tuple[subprocess.Popen, float]) -> None:
        p, t = started
        _, err = p.communicate(timeout=600)
        self.seconds = time.perf_counter() - t
        if p.returncode != 0:
            raise RuntimeError(f"{self.name} failed: {err[-2000:]}")
        self.new = snapshot(self.out)

    def kill_once(self, rng: np.random.Generator) -> str:
        """Put the old output back, start the command, SIGKILL it after a random part of
        its usual duration (sometimes after it finished), classify the output."""
        self.put_old()
        p = subprocess.Popen(S2P + [str(a) for a in self.argv], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             env=ENV)
        deadline = time.perf_counter() + rng.uniform(0.15, 1.05) * self.seconds
        while p.poll() is None and time.perf_counter() < deadline:
            time.sleep(0.01)
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.wait()
        kind = classify(snapshot(self.out), snapshot(self.old), self.new)
        self.counts[kind] += 1
        return kind

    def leftovers(self) -> list[str]:
        """Hidden siblings of the output (temporary builds, locks)."""
        return sorted(p.name for p in self.out.parent.iterdir()
                      if p.name.startswith(f".{self.out.name}."))

    def live_leftovers(self) -> list[str]:
        """Leftovers that the next writer would not remove: partial outputs of processes
        that still run, or anything not named like a partial output or a lock."""
        from seg2pose.io.atomic import _PARTIAL, pid_alive

        out = []
        for n in self.leftovers():
            m = _PARTIAL.match(n)
            if n == f".{self.out.name}.lock":
                continue
            if not m or pid_alive(int(m.group("pid"))):
                out.append(n)
        return out


def build_cases(root: Path, frames: int = 40) -> list[Case]:
    """The five commands of issue 10 on small inputs under ``root``: s2p run, synth,
    convert-masks, import-utocs and export, each with an old output to replace."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hostile_fixtures import write_scene, write_utocs
    from seg2pose.io.mask_formats import save_masks
    from seg2pose.io.mots import read_mots
    from seg2pose.io.utocs import import_utocs
    from seg2pose.method.pipeline import run_scene
    from seg2pose.synth.generate import generate_scene
    from s2p_review.mcap_export import export_mcap
    from seg2pose.io.scene import load_scene

    root.mkdir(parents=True, exist_ok=True)
    scene = write_scene(root / "scene", frames=frames, users=4)
    other = write_scene(root / "other", frames=5, users=2)
    old = root / "old"
    old.mkdir()
    run_scene(other, old / "run", baseline=True, progress=False)
    run_scene(scene, root / "run", baseline=True, progress=False)
    generate_scene(old / "synth", frames=3, seed=1, workers=1, progress=False)
    save_masks(old / "png", read_mots(other.masks_path("c0")), "png")
    import_utocs(write_utocs(root / "utocs-a", frames=2), old / "utocs", log=lambda *a: None)
    write_utocs(root / "utocs-b", frames=frames, images=True)
    export_mcap(load_scene(other.root), old / "run", old / "x.mcap")
    out = root / "out"
    out.mkdir()
    return [
        Case("run", ["run", scene.root, "-o", out / "run", "--baseline", "--force"], out / "run", old / "run"),
        Case("synth", ["synth", "-o", out / "synth", "--frames", "6", "--seed", "2", "--workers", "1", "--no-progress",
                       "--force"], out / "synth", old / "synth"),
        Case("convert-masks", ["convert-masks", scene.masks_path("c0"), "-o", out / "png", "--format", "png",
                               "--force"], out / "png", old / "png"),
        Case("import-utocs", ["import-utocs", root / "utocs-b", "-o", out / "utocs", "--force"], out / "utocs",
             old / "utocs"),
        Case("export", ["export", scene.root, "--run", root / "run", "-o", out / "x.mcap", "--force"],
             out / "x.mcap", old / "x.mcap"),
    ]
