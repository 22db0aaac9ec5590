"""Fault injection for the kill tests (tests/system/test_kill.py, benches/bench_faults.py):
the commit steps where a writer killed is hardest to survive, and two ways of killing it
there. Inert unless the environment asks (``S2P_KILL_AT``, ``S2P_KILL_FORKS``).

``commit_step(STEP)`` marks a step: "built" (a single output durable, before its swap),
"swapped" (after a single output's swap, before the old one is removed), "recorded" (a set's
commit records durable, before its first swap), "set-swap" (after each swap of a set),
"unrecorded" (a set's records removed, before its old outputs are), "appended" (an annotation
journal's record durable: annotate.journal) and "done" (the end of one commit).

- ``S2P_KILL_AT="STEP:N"``: this process SIGKILLs itself the N-th time (from 1) it reaches
  STEP; ``"STEP:N:SECONDS"``: that many seconds after it (a timer: the kernel ends the process
  with SIGALRM's default action, which, like SIGKILL, runs no handler and flushes nothing),
  wherever the commit has got to by then.
- ``S2P_KILL_FORKS="K,SOCKET"`` (the kill harness, tests/kill_harness.py): at the start of
  the first commit of each kind of output (folder, suffix; ``commit_entry``) the process
  (the command, or a process it started: a Ray worker) forks K children per step of that
  commit, one after another; each goes on with the commit and is killed at the step (exactly,
  at each time the commit reaches it, then after sub-delays of 0.1-51 ms). After each death
  the harness, listening on the Unix socket SOCKET, is told (``killed STEP N SECONDS
  STATUS``), judges the outputs as the next writer finds them and answers; the commit's
  folders are then put back as they were at the fork. Then the process commits for real.
  A kill costs the commit, not the computation before it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import tempfile
from pathlib import Path

_reached: dict[str, int] = {}
_armed = False  # a timed kill is due (the kill harness ends a command that finished first)
_seen: set[tuple[Path, str]] = set()  # S2P_KILL_FORKS: the kinds of output killed at already
_child = False  # a forked child of S2P_KILL_FORKS: it ends at the end of its commit
# sub-delays of the kills after the exact ones: points inside and after the step's commit
DELAYS = [1e-4 * 2 ** i for i in range(10)]  # 0.1 ms .. 51 ms


def commit_step(step: str) -> None:
    """Mark the commit step ``step`` (see above); a no-op unless S2P_KILL_AT names it."""
    global _armed
    kill_at = os.environ.get("S2P_KILL_AT")
    if not kill_at:
        return
    _reached[step] = _reached.get(step, 0) + 1
    name, n, delay = (kill_at.split(":") + ["", ""])[:3]
    if step == "done" and _child:  # the commit is over: so is this child (reached or not)
        os.kill(os.getpid(), signal.SIGKILL) if _armed else os._exit(3)
    if name != step or _reached[step] != int(n or 1):
        return
    if not float(delay or 0) > 0:
        os.kill(os.getpid(), signal.SIGKILL)
    with contextlib.suppress(ValueError):  # only the main thread may (it is SIG_DFL already)
        signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.setitimer(signal.ITIMER_REAL, float(delay))
    _armed = True


def commit_entry(steps: list[tuple[str, int]], builds: list[Path], finals: list[Path]) -> None:
    """The start of a commit that reaches each of ``steps`` (step, times) and puts ``builds``
    at ``finals``: with S2P_KILL_FORKS, the forked kills described above; else nothing."""
    global _child
    spec = os.environ.get("S2P_KILL_FORKS")
    if not spec or _child:
        return
    k, _, sock = spec.partition(",")
    per_step = int(k)
    from seg2pose.io.atomic_names import is_temporary

    if all(any(is_temporary(a.name) for a in Path(f).parents) for f in finals):
        return  # files put inside a build: no reader sees them before the build is swapped in
    kinds = {(Path(f).parent, Path(f).suffix) for f in finals}
    if kinds <= _seen:  # killed at the first commit of each kind of output (folder, suffix)
        return
    _seen.update(kinds)
    folders = list(dict.fromkeys(Path(p).parent for p in [*builds, *finals]))
    keep = Path(tempfile.mkdtemp(prefix="s2p-kill-keep-"))
    try:
        marks = [_checkpoint(f, keep / str(i)) for i, f in enumerate(folders)]
        for step, times in steps:
            for i in range(per_step):
                n, delay = 1 + i % times, 0.0 if i < times else DELAYS[i - times]
                child = os.fork()
                if child == 0:
                    _child = True
                    _reached.clear()
                    os.environ["S2P_KILL_AT"] = f"{step}:{n}:{delay}"
                    return  # into the commit, to die in it
                _, status = os.waitpid(child, 0)
                _tell(sock, f"killed {step} {n} {delay} {os.waitstatus_to_exitcode(status)}\n")
                marks = [_restore(f, keep / str(i), m) for i, (f, m) in enumerate(zip(folders, marks))]
    finally:
        if not _child:
            shutil.rmtree(keep, ignore_errors=True)


_chan: dict[int, socket.socket] = {}  # this process's connection to the harness


def _tell(path: str, line: str) -> None:
    """Say ``line`` to the harness listening at ``path``; return once it answers."""
    if os.getpid() not in _chan:
        _chan.clear()  # a forked process's parent's connection is not its own
        _chan[os.getpid()] = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        _chan[os.getpid()].connect(path)
    c = _chan[os.getpid()]
    c.sendall(line.encode())
    if not c.recv(64):  # the harness has judged what the kill left
        raise RuntimeError("the kill harness went away")


def _skip(name: str) -> bool:
    """Locks stay as they are: the command holds them (by their inode) throughout."""
    return name == "lock" or name.endswith(".lock")


def _sig(p: Path) -> object:
    """What tells a changed entry from an unchanged one: inode, size and time of a file or
    link; of a folder, also its entries'."""
    st = os.lstat(p)
    if p.is_dir() and not p.is_symlink():
        return (st.st_ino, tuple((c.name, _sig(c)) for c in sorted(p.iterdir())))
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _put(src: Path, dst: Path) -> None:
    if src.is_dir() and not src.is_symlink():
        shutil.copytree(src, dst, symlinks=True)
    else:
        shutil.copy2(src, dst, follow_symlinks=False)


def _checkpoint(folder: Path, keep: Path) -> dict[str, object]:
    """Copy the entries of ``folder`` (but locks) to ``keep``; their signatures."""
    keep.mkdir()
    marks = {}
    if folder.is_dir():
        for e in sorted(folder.iterdir()):
            if not _skip(e.name):
                _put(e, keep / e.name)
                marks[e.name] = _sig(e)
    return marks


def _restore(folder: Path, keep: Path, marks: dict[str, object]) -> dict[str, object]:
    """Put ``folder`` back as ``_checkpoint`` found it: entries added since removed, changed
    or missing ones copied back from ``keep`` (unchanged ones, which the command may hold
    open, untouched). The signatures now."""
    now = {e.name: e for e in folder.iterdir() if not _skip(e.name)} if folder.is_dir() else {}
    out = {}
    for name, e in now.items():
        if name not in marks or _sig(e) != marks[name]:
            shutil.rmtree(e) if e.is_dir() and not e.is_symlink() else e.unlink()
    for name in marks:
        p = folder / name
        if not (p.exists() or p.is_symlink()):
            folder.mkdir(parents=True, exist_ok=True)
            _put(keep / name, p)
        out[name] = _sig(p)
    return out
