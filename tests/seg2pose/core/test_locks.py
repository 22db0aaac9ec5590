"""The one lock-holder record and alive check (seg2pose/core/locks.py) and its two lock files:
exclusive (outputs) and kernel-released (the annotation journal)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest

from seg2pose.core.locks import ExclusiveLock, KernelLock, LockHolder, pid_alive


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


class Busy(Exception):
    pass


def test_holder_record_round_trip_and_old_files():
    me = LockHolder.me()
    assert me.pid == os.getpid() and me.host == socket.gethostname() and not me.gone
    assert LockHolder.parse(me.to_json()) == me
    # older output locks named the start "time"; a record without one says "?"
    assert LockHolder.parse('{"pid": 7, "host": "h", "time": "T"}') == LockHolder(7, "h", "T")
    assert LockHolder.parse('{"pid": 7, "host": "h"}').since == "?"
    for bad in ("", "{}", "not json", '{"pid": "x", "host": "h"}', "[1]", '{"pid": 3'):
        assert LockHolder.parse(bad) is None


def test_alive_check():
    assert pid_alive(os.getpid())
    assert not pid_alive(dead_pid()) and not pid_alive(0) and not pid_alive(-1)
    assert not pid_alive(2 ** 80)
    assert LockHolder(dead_pid(), socket.gethostname()).gone
    assert not LockHolder(dead_pid(), "another-host").gone  # cannot tell: not taken over


def test_a_zombie_holds_nothing(tmp_path):
    """A process that has ended but was not collected yet (a zombie: a killed Ray worker
    whose new parent is slow to collect it) is not alive: its output lock is taken over."""
    import time

    pid = os.fork()
    if pid == 0:
        os._exit(0)
    try:
        for _ in range(500):  # until it has ended (not collected: a zombie of this process)
            with open(f"/proc/{pid}/stat", "rb") as f:
                if f.read().rsplit(b")", 1)[1].split()[0] == b"Z":
                    break
            time.sleep(0.01)
        assert not pid_alive(pid)
        path = tmp_path / ".out.lock"
        path.write_text(LockHolder(pid, socket.gethostname(), "T0").to_json())
        assert ExclusiveLock(path, Busy).acquire()
    finally:
        os.waitpid(pid, 0)


def test_a_pid_reused_by_a_later_process_is_not_the_holder(tmp_path):
    """pids are reused (32,768 on many machines): a process that started after the lock was
    taken (or a partial file last written) is not its holder."""
    import datetime as dt
    import time

    me = os.getpid()
    assert pid_alive(me, time.time()) and pid_alive(me)
    assert not pid_alive(me, time.time() - 10 * 86400)  # this process did not run then
    old = (dt.datetime.now(dt.UTC) - dt.timedelta(days=10)).isoformat(timespec="seconds")
    assert LockHolder(me, socket.gethostname(), old).gone
    assert not LockHolder(me, socket.gethostname(), "?").gone  # no time: cannot tell
    path = tmp_path / ".out.lock"
    path.write_text(LockHolder(me, socket.gethostname(), old).to_json())
    assert ExclusiveLock(path, Busy).acquire()


def test_exclusive_lock_refuses_a_live_holder_and_takes_over_a_gone_one(tmp_path):
    path = tmp_path / ".out.lock"
    seen = []
    a = ExclusiveLock(path, Busy, seen.append)
    assert a.acquire() and LockHolder.parse(path.read_text()).pid == os.getpid()
    with pytest.raises(Busy) as e:
        ExclusiveLock(path, Busy).acquire()
    assert e.value.args[0].pid == os.getpid()
    a.release()
    assert not path.exists()
    gone = LockHolder(dead_pid(), socket.gethostname(), "T0")
    path.write_text(gone.to_json())
    assert ExclusiveLock(path, Busy, seen.append).acquire()
    path.write_text("")  # a holder killed between creating the file and writing its record
    assert ExclusiveLock(path, Busy, seen.append).acquire()
    assert seen == [gone, None]
    path.write_text(json.dumps({"pid": 1, "host": "elsewhere"}))  # another host's: kept
    with pytest.raises(Busy):
        ExclusiveLock(path, Busy, seen.append).acquire()


def test_kernel_lock_names_its_holder_and_the_one_before(tmp_path):
    path = tmp_path / "lock"
    gone = LockHolder(dead_pid(), socket.gethostname(), "T0")
    path.write_text(gone.to_json())
    a = KernelLock(path, Busy)
    assert a.previous == gone and a.holder().pid == os.getpid()
    # flock is per open file description: a second open in this process is refused too
    with pytest.raises(Busy) as e:
        KernelLock(path, Busy)
    assert e.value.args[0].pid == os.getpid()
    a.release()
    a.release()  # idempotent
    assert path.exists() and path.read_text() == ""
    b = KernelLock(path, Busy)
    assert b.previous is None
    b.release()
