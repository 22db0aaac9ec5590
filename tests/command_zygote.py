"""Commands run in processes forked from one Python that has imported s2p already
(``Zygote``, ``zygote()``): a command's time is its own, not the second or two a new
interpreter needs to import the project. What a command writes and how it is killed
(SIGKILL, nothing flushed, no handler run) is the same as for a command started from the
shell. Also what a killed command leaves running: ``descendants``, ``ray_workers_of``,
``wait_gone`` (from /proc). Used by tests/kill_harness.py and tests/system/test_writers.py."""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}

_ZYGOTE = r"""
import json, os, sys, tempfile, traceback
sys.argv = ["s2p"]
import numpy, cv2                      # what every command imports, loaded once
cv2.setNumThreads(1)  # tiny frames: a thread pool per forked command costs more than it saves
import seg2pose.cli, seg2pose.video.video_scene, seg2pose.method.pipeline, seg2pose.batch.steps
import seg2pose.io.tacal, annotate, annotate.tanalyst_io, s2p_review.mcap_export
import seg2pose.batch.segments, seg2pose.eval.evaluate, annotate.export, s2p_review.annotated_mcap
import torch, seg2pose.method.net, seg2pose.method.sparse  # `run` imports torch (no thread starts on import)
import typer, typer._adapters, typer._coercion, typer.core, typer.main, pydantic, tqdm
import zoneinfo, fractions, email.utils, multiprocessing.synchronize, mcap_protobuf.writer
for m in ("Color", "CameraCalibration", "FrameTransform", "SceneUpdate", "PosesInFrame",
          "ImageAnnotations", "Point2", "PointsAnnotation", "RawImage"):
    __import__(f"foxglove_schemas_protobuf.{m}_pb2")
out = os.fdopen(1, "w", buffering=1)
out.write("ready\n")
for line in sys.stdin:
    argv, err, env = json.loads(line)
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.environ.update(env)  # S2P_KILL_AT: a kill at a commit step (seg2pose.io.kill_points)
            tempfile.tempdir = None  # a TMPDIR of the command's own counts
            os.setpgid(0, 0)
            null = os.open(os.devnull, os.O_RDWR)
            os.dup2(null, 0)
            os.dup2(os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), 2)
            os.dup2(2, 1)  # what it says too: batch reports a scene's failure in its table
            sys.argv = ["s2p", *argv]
            from seg2pose.cli import main
            main()
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except BaseException:
            traceback.print_exc()
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
                from seg2pose.io import kill_points
                if kill_points._armed:  # S2P_KILL_AT: a kill timed after a step is due: not before the end
                    os.kill(os.getpid(), 9)
            finally:
                os._exit(code)
    out.write(f"{pid}\n")
    _, status = os.waitpid(pid, 0)
    out.write(f"{status}\n")
"""


class Zygote:
    """A Python that has imported s2p and forks one child per command. ``start(argv)`` ->
    the child's pid; ``wait(timeout)`` -> its exit code (negative: the signal that ended it),
    None while it runs. One command at a time."""

    def __init__(self):
        self.p = subprocess.Popen([sys.executable, "-c", _ZYGOTE], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, env=ENV, text=False)
        self.buf = b""
        self.err = Path(os.environ.get("TMPDIR", "/tmp")) / f"s2p-kill-{os.getpid()}-{id(self)}.err"
        if self._line(600) != "ready":  # imports done: a command's time is its own from here
            raise RuntimeError("the kill harness's Python did not start")

    def _line(self, timeout: float | None) -> str | None:
        end = None if timeout is None else time.perf_counter() + timeout
        while b"\n" not in self.buf:
            left = None if end is None else max(0.0, end - time.perf_counter())
            r, _, _ = select.select([self.p.stdout], [], [], left)
            if not r:
                return None
            chunk = os.read(self.p.stdout.fileno(), 4096)
            if not chunk:
                raise RuntimeError("the kill harness's Python ended")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line.decode()

    def start(self, argv: list, env: dict | None = None) -> int:
        self.p.stdin.write((json.dumps([[str(a) for a in argv], str(self.err), env or {}]) + "\n").encode())
        self.p.stdin.flush()
        return int(self._line(60))

    def wait(self, timeout: float | None = None) -> int | None:
        line = self._line(timeout)
        if line is None:
            return None
        status = int(line)
        return os.waitstatus_to_exitcode(status)

    def error_text(self) -> str:
        try:
            return self.err.read_text(errors="replace")[-2000:]
        except OSError:
            return ""

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self.p.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.p.wait(timeout=30)
        self.err.unlink(missing_ok=True)


_zygote: Zygote | None = None


def zygote() -> Zygote:
    global _zygote
    if _zygote is None or _zygote.p.poll() is not None:
        _zygote = Zygote()
        atexit.register(_zygote.close)  # its Python ends, and its error file goes
    return _zygote


def descendants(pid: int) -> list[int]:
    """The processes started by ``pid``, and by those, and so on (from /proc)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                stat = Path(f"/proc/{d}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(d))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def ray_workers_of(pids: list[int]) -> list[int]:
    """Processes whose environment names one of ``pids`` as their raylet (Ray's workers)."""
    want = {f"RAY_RAYLET_PID={p}".encode() for p in pids}
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                env = Path(f"/proc/{d}/environ").read_bytes().split(b"\0")
            except OSError:
                continue
            if want.intersection(env):
                out.append(int(d))
    return out


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"
    except OSError:
        return False


def wait_gone(pids: list[int], timeout: float = 120.0) -> list[int]:
    """Wait until the processes ``pids`` have ended (zombies count as ended); those still
    running after ``timeout`` seconds."""
    end = time.perf_counter() + timeout
    while True:
        left = [p for p in pids if _running(p)]
        if not left or time.perf_counter() > end:
            return left
        time.sleep(0.1)
