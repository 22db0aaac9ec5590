"""Kill s2p commands at random moments and classify what they leave under the outputs' names:
``absent``, ``old`` (the complete previous outputs), ``new`` (the complete new ones) or
``mixed`` (anything else: a partial or merged output, or a set of outputs of which some are
old and some new). Used by tests/system/test_kill.py (4-10 kills a command) and
benches/bench_faults.py (many); the commands they kill are tests/kill_cases.py's.

The commands run in processes forked from one Python that has imported s2p already
(tests/command_zygote.py): a kill costs the command's own time, not the second or two a new
interpreter needs to import the project."""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from command_zygote import descendants, ray_workers_of, wait_gone, zygote


def snapshot(path: Path) -> dict | None:
    """The content of an output: None when absent; {relative path: bytes} of its files
    (a file output: {'': bytes}). run.json's creation time and ids.json's times are left out
    (they differ between two runs of the same command). Hidden siblings are not part of it."""
    if not path.exists():
        return None
    if path.is_file():
        return {"": _normalized(path)}
    return {str(p.relative_to(path)): _normalized(p) for p in sorted(path.rglob("*")) if p.is_file()}


def _normalized(p: Path) -> bytes:
    """A file's bytes without the times two runs of a command write differently."""
    data = p.read_bytes()
    if p.name == "run.json":
        d = json.loads(data)
        d.pop("created", None)
        data = json.dumps(d, sort_keys=True).encode()
    elif p.name == "ids.json":  # masks/ids.json: when each camera's ids were made
        d = json.loads(data)
        for e in d.get("cameras", {}).values():
            e.pop("made", None)
        data = json.dumps(d, sort_keys=True).encode()
    return data


def classify(state: dict | None, old: dict | None, new: dict) -> str:
    if state is None:
        return "absent"
    if state == new:
        return "new"
    if state == old:
        return "old"
    return "mixed"



def _copy(src: Path | None, dst: Path) -> None:
    """Put ``src`` (a file, a folder, or None: nothing) at ``dst``."""
    if dst.is_dir() and not dst.is_symlink():
        shutil.rmtree(dst)
    elif dst.exists() or dst.is_symlink():
        dst.unlink()
    if src is None:
        return
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        shutil.copy2(src, dst)


@dataclass
class Case:
    """One command: ``argv`` writes the outputs ``outs`` (with --force where it needs it);
    ``olds`` are the complete outputs it replaces (files or folders copied into place before
    every kill; None: the output is absent before). ``state`` (default: the bytes of every
    output, ``snapshot``) is what is compared; ``resume`` (batch): after a kill, run again as
    a user would and say whether the result is the uninterrupted run's."""

    name: str
    argv: list
    outs: list
    olds: list
    state: Callable | None = None
    resume: bool = False
    rerun: list | None = None  # the re-run after a kill (default: argv without --force)
    tree: bool = False  # wait for the killed command's other processes (Ray's) to end
    env: dict | None = None  # the command's environment besides the harness's (its TMPDIR)
    stray: int = 0  # of those, still running 120 s after the kill
    new: object = None
    seconds: float = 1.0
    counts: dict = field(default_factory=lambda: {"absent": 0, "old": 0, "new": 0, "between": 0,
                                                  "mixed": 0, "finished": 0})
    mixed: list = field(default_factory=list)  # per mixed kill: each output's state, leftovers

    def __post_init__(self) -> None:
        self.outs = [Path(o) for o in self.outs]
        self.olds = [None if o is None else Path(o) for o in self.olds]

    @property
    def out(self) -> Path:
        return self.outs[0]

    def snap(self):
        if self.state is not None:
            return self.state(self)
        return [snapshot(o) for o in self.outs]

    def put_old(self) -> None:
        for o, old in zip(self.outs, self.olds):
            _copy(old, o)

    def old_state(self):
        if not hasattr(self, "_old"):
            self.put_old()
            self._old = self.snap()
        return self._old

    def run_fully(self) -> None:
        """Run to the end once: the reference new outputs and the command's duration."""
        self.old_state()
        self.put_old()
        z = zygote()
        t = time.perf_counter()
        z.start(self.argv, self.env)
        code = z.wait(600)
        self.seconds = time.perf_counter() - t
        if code != 0:
            raise RuntimeError(f"{self.name} failed ({code}): {z.error_text()}")
        self.new = self.snap()

    def classify(self) -> str:
        st, old, new = self.snap(), self._old, self.new
        if st == new:
            return "new"
        if st == old:
            return "old"
        if all(x is None for x in st):
            return "absent"
        if self.resume and all(x is None or x == o or x == n for x, o, n in zip(st, old, new)):
            return "between"  # some outputs done, each one whole: the re-run goes on from there
        return "mixed"

    def kill_at(self, step: str, n: int = 1, delay: float = 0.0) -> str:
        """Like ``kill_once``, but the command kills itself (SIGKILL) the ``n``-th time it
        reaches the commit step ``step`` (``seg2pose.io.kill_points.commit_step``), or
        ``delay`` seconds after it; a command that never reaches it runs to its end. Returns
        the kind, or "not reached"."""
        return self.kill_once(None, env={"S2P_KILL_AT": f"{step}:{n}:{delay}"})

    def kill_once(self, rng: np.random.Generator | None, share: tuple[float, float] = (0.15, 1.05),
                  env: dict | None = None) -> str:
        """Put the old outputs back, start the command, SIGKILL it after a random ``share`` of
        its usual duration (sometimes after it finished), classify the outputs. With ``resume``
        the command is then run again (without --force, as after a crash) and a re-run that
        fails or does not end with the uninterrupted run's outputs counts as ``mixed``. Then
        what the next writer does first is done (``finish_commits``); a mixed set that this
        makes the new one is also counted as ``finished``."""
        self.old_state()
        self.put_old()
        z = zygote()
        pid = z.start(self.argv, {**(self.env or {}), **(env or {})})
        code = z.wait(rng.uniform(*share) * self.seconds if rng is not None else 600)
        if env and code == 0:  # the step was not reached: nothing to count
            self.put_old()
            return "not reached"
        if code is None:
            tree = descendants(pid) if self.tree else []
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
            z.wait()
            # Ray's processes (own process groups) end when the driver's raylet does; a task
            # may still finish its write meanwhile: the outputs are what they leave (a worker
            # forked just after the list was taken is found by its raylet's pid)
            if tree:
                tree += [p for p in ray_workers_of(tree) if p not in tree]
            self.stray += len(wait_gone(tree))
        return self._judge(timed=bool(env))

    def kill_forks(self, per_step: int = 10) -> dict[str, list[str]]:
        """Kills timed at every commit step, ``per_step`` per step of each commit the command
        makes (``seg2pose.io.kill_points``: S2P_KILL_FORKS): the command runs once; at each
        commit it forks children that go on with the commit and die at the step (exactly, at
        each time the commit reaches it, then after sub-delays of 0.1-26 ms); each death is
        judged here as the next writer finds the outputs (``_judge``; no re-run of a resuming
        command: its outputs must each be whole), the commit's folders are put back, and the
        command finally commits for real and must end with the new outputs. Returns the kinds
        per step."""
        self.old_state()
        self.put_old()
        kinds: dict[str, list[str]] = {}
        problems: list[str] = []
        folder = tempfile.mkdtemp(prefix="s2pk-")  # short: a Unix socket's path is <= 107 bytes
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        listener.bind(f"{folder}/k")
        listener.listen()

        def serve() -> None:  # judge each kill of any process of the command (Ray's workers too)
            conns: list[socket.socket] = []
            files = {}
            while True:
                try:
                    r, _, _ = select.select([listener, *conns], [], [])
                except (OSError, ValueError):  # the listener closed under select: the command ended
                    return
                for c in r:
                    if c is listener:
                        try:
                            conn, _ = listener.accept()
                        except OSError:  # closed: the command has ended
                            return
                        conns.append(conn)
                        files[conn] = conn.makefile("rb")
                        continue
                    line = files[c].readline().decode()
                    if not line:
                        conns.remove(c)
                        continue
                    _, step, _n, _delay, status = line.split()
                    if int(status) == 3:  # the child's commit ended without reaching the step
                        problems.append(f"{line.strip()}: the step was not reached")
                    kinds.setdefault(step, []).append(self._judge(timed=True, rerun=False))
                    c.sendall(b"go\n")

        server = threading.Thread(target=serve, daemon=True)
        server.start()
        z = zygote()
        try:
            z.start(self.argv, {**(self.env or {}), "S2P_KILL_FORKS": f"{per_step},{folder}/k"})
            code = z.wait(1200)
        finally:
            listener.shutdown(socket.SHUT_RDWR)
            listener.close()
            server.join(30)
            shutil.rmtree(folder, ignore_errors=True)
        if code != 0 or problems:
            raise RuntimeError(f"{self.name}: after its forked kills: exit {code}, {problems}: {z.error_text()}")
        if self.snap() != self.new:
            self.counts["mixed"] += 1
            self.mixed.append((["the command's own commit after its forked kills: not the new outputs"],
                               self.leftovers()))
        return kinds

    def _judge(self, timed: bool, rerun: bool = True) -> str:
        """Classify what a kill left, do what the next writer does first, and count."""
        kind = self.classify()
        if kind == "mixed":  # which outputs were what, and what lay beside them
            st = self.snap()
            self.mixed.append(([("new" if x == n else "old" if x == o else "absent" if x is None
                                 else "other") for x, o, n in zip(st, self._old, self.new)],
                               self.leftovers()))
        # what the next writer of any output does first: finish a set commit the killed one
        # recorded (so the old outputs put back for the next kill are not mixed with its builds)
        from seg2pose.io.atomic import finish_commits

        for o in self.outs:
            finish_commits(o)
        if kind == "mixed" and self.classify() == "new":
            self.counts["finished"] += 1
            if timed:  # a kill timed among a set's swaps: judged after the next writer's first step
                kind = "new"
                self.mixed.pop()
        if self.resume and kind != "mixed" and rerun:
            z = zygote()
            z.start(self.rerun or [a for a in self.argv if a != "--force"], self.env)
            code = z.wait(600)
            if code != 0 or self.snap() != self.new:
                kind = "mixed"
                self.mixed.append(([f"the re-run after a {kind} kill: exit {code}",
                                    z.error_text()[-400:]], self.leftovers()))
        self.counts[kind] = self.counts.get(kind, 0) + 1
        return kind

    def leftovers(self) -> list[str]:
        """Hidden siblings of the outputs (temporary builds, locks, commit records)."""
        out = []
        for o in self.outs:
            if o.parent.is_dir():
                out += sorted(p.name for p in o.parent.iterdir() if p.name.startswith(f".{o.name}.")
                              or p.name.startswith(f"..{o.name}."))
        return out

    def live_leftovers(self) -> list[str]:
        """Leftovers that the next writer would not remove: partial outputs of processes
        that still run, or anything not named like a partial output, a commit record or a
        lock."""
        from seg2pose.core.locks import pid_alive
        from seg2pose.io.atomic_names import COMMIT_RECORD, owner

        out = []
        for n in self.leftovers():
            if n.endswith(".lock") and n[1:-5] in {o.name for o in self.outs}:
                continue
            own = owner(n)
            if own is not None and not any(pid_alive(p) for p in own[1]):
                continue
            m = COMMIT_RECORD.match(n)
            if m and not pid_alive(int(m.group("pid"))):
                continue
            out.append(n)
        return out


