"""Issue 38: one way to write, groups (5) leftovers and locks -- no headless viewer, state
folder or partial recording left by a killed command, every output locked from the start --
and (6) one-line messages that name the output. Groups (1)-(4): tests/system/test_write_path.py."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest
from video_fixtures import single_threaded_opencv

from seg2pose.core.clock import utc_now
from seg2pose.core.errors import S2PError
from seg2pose.core.locks import LockHolder

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)


# --- (5) leftovers and locks ----------------------------------------------------------------------

def _processes_with_env(text: str) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                env = Path(f"/proc/{d}/environ").read_bytes()
                state = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if text.encode() in env and state not in "ZX":
                out.append(int(d))
    return out


def test_a_killed_command_leaves_no_headless_viewer_and_no_state_folder(tmp_path):
    """``s2p screenshot`` SIGKILLed while its headless viewer runs (the viewer, ~700 MB, kept
    running in 8 of 16 kills, and every headless viewer left /tmp/s2p-viewer-state-*)."""
    import signal
    import subprocess
    import sys
    import time

    from s2p_review.viewer import vulkan_problem

    if vulkan_problem():
        pytest.skip(f"no headless viewer here: {vulkan_problem()}")
    code = ("from s2p_review.viewer import spawn_viewer\nc = spawn_viewer(headless=True)\n"
            "print(c._pid, flush=True)\nimport time\ntime.sleep(600)\n")
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    try:
        viewer = int(p.stdout.readline())
        states = [d for d in tmp_path.iterdir() if d.name.startswith("s2p-viewer-state-")]
        assert len(states) == 1 and _processes_with_env(str(states[0])) != []
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
    end = time.monotonic() + 20
    while time.monotonic() < end and (_processes_with_env(str(states[0])) or states[0].exists()):
        time.sleep(0.2)
    assert _processes_with_env(str(states[0])) == [], f"viewer {viewer} still runs"
    assert not states[0].exists()


def test_the_annotation_server_ends_with_the_command_that_started_it(tmp_path):
    """A SIGKILLed ``s2p annotate`` left its server listening: the server is started with a
    parent-death signal (``annotate.app.serve.die_with_parent``), here on a stand-in child."""
    import signal
    import subprocess
    import sys
    import time

    code = ("import subprocess, sys\nfrom annotate.app.serve import die_with_parent\n"
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'], "
            "start_new_session=True, preexec_fn=die_with_parent)\n"
            "print(p.pid, flush=True)\nimport time\ntime.sleep(600)\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(p.stdout.readline())
    p.send_signal(signal.SIGKILL)
    p.wait()
    end = time.monotonic() + 10
    while time.monotonic() < end and _running(child):
        time.sleep(0.1)
    assert not _running(child)


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"
    except OSError:
        return False


def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_killed_review_s_partial_recording_is_removed_by_the_next_one(tmp_path):
    """``s2p review -o r.rrd`` killed left .r.rrd.partial-PID-x.rrd for good (7 of 10 kills):
    the next writer of r.rrd (``atomic_path``, which the recording is written through) removes
    those of processes that no longer run, and keeps a live one's."""
    from seg2pose.io.atomic import atomic_path

    dead = tmp_path / f".r.rrd.partial-{_dead_pid()}-k3x9.rrd"
    dead.write_bytes(b"half a recording")
    live = tmp_path / f".r.rrd.partial-{os.getpid()}-live.rrd"
    live.write_bytes(b"being written")
    with atomic_path(tmp_path / "r.rrd") as tmp:
        tmp.write_bytes(b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, "r.rrd"])


def test_review_and_screenshot_lock_their_outputs_from_the_start(tmp_path):
    """A second ``s2p review -o`` / ``s2p screenshot`` of the same file is refused before any
    work (neither took a lock: two wrote the same file, the last one won)."""
    from hostile_fixtures import write_scene

    from s2p_review.session import record
    from s2p_review.viewer import take_screenshot
    from seg2pose.io.scene import load_scene

    scene = load_scene(write_scene(tmp_path / "scene", frames=2, users=1).root)
    other = LockHolder(os.getppid(), socket.gethostname(), utc_now()).to_json()  # a live writer
    (tmp_path / ".r.rrd.lock").write_text(other)
    with pytest.raises(S2PError, match=rf"r\.rrd is being written by process {os.getppid()}"):
        record(scene, [], tmp_path / "r.rrd")
    (tmp_path / "x.rrd").write_bytes(b"")
    (tmp_path / ".s.png.lock").write_text(other)
    with pytest.raises(S2PError, match=rf"s\.png is being written by process {os.getppid()}"):
        take_screenshot(tmp_path / "x.rrd", tmp_path / "s.png")
    assert not (tmp_path / "r.rrd").exists() and not (tmp_path / "s.png").exists()


def test_run_locks_its_folder_from_the_start(tmp_path, monkeypatch):
    """Two ``s2p run`` into one folder both computed and the last one won: the second is now
    refused before computing anything (the lock is held from the start)."""
    from hostile_fixtures import write_scene

    import seg2pose.method.pipeline as P

    scene = write_scene(tmp_path / "scene", frames=2, users=1)
    (tmp_path / ".run.lock").write_text(LockHolder(os.getppid(), socket.gethostname(),
                                                   utc_now()).to_json())

    def computes(*a, **k):
        raise AssertionError("computed although another run holds the folder")

    monkeypatch.setattr(P, "compute_views", computes)
    with pytest.raises(S2PError, match=r"run is being written by process"):
        P.run_scene(scene, tmp_path / "run", P.RunOptions(baseline=True, progress=False))


# --- (6) one line that names the output --------------------------------------------------------------

def test_a_full_disk_names_the_output(tmp_path, monkeypatch, capsys):
    """``s2p export`` on a full disk said ``error: ?: the disk is full``: the line now names
    the output being written, and the old output stays."""
    import errno
    import sys

    from hostile_fixtures import write_scene

    import s2p_review.mcap_export as ME
    from seg2pose.cli import main
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = write_scene(tmp_path / "scene", frames=3, users=1)
    run_scene(scene, tmp_path / "run", RunOptions(baseline=True, progress=False))

    def full(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ME._Writer, "write", full)
    out = tmp_path / "x.mcap"
    monkeypatch.setattr(sys, "argv", ["s2p", "export", str(scene.root), "--run", str(tmp_path / "run"),
                                      "-o", str(out)])
    with pytest.raises(SystemExit) as e:
        main()
    assert e.value.code == 2
    assert capsys.readouterr().err.strip() == f"error: cannot write {out}: the disk is full"
    assert not out.exists() and not out.with_suffix(".layout.json").exists()


def test_calibrate_locks_its_output_before_fitting(tmp_path, monkeypatch):
    """``s2p calibrate-errors`` took no lock: two fits into one file both computed."""
    from scene_fixtures import make_tiny_scene

    import seg2pose.method.r90_calibrate as RC
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = make_tiny_scene(tmp_path / "s", frames=20, n_users=4)
    run_scene(scene, tmp_path / "val", RunOptions(baseline=True, split="val", progress=False))
    (tmp_path / ".r90.json.lock").write_text(LockHolder(os.getppid(), socket.gethostname(),
                                                        utc_now()).to_json())

    def fits(*a, **k):
        raise AssertionError("fitted although another process holds the output")

    monkeypatch.setattr(RC, "fit_calibration", fits)
    with pytest.raises(S2PError, match=r"r90\.json is being written by process"):
        RC.calibrate_run(scene, tmp_path / "val", tmp_path / "r90.json")


def test_conflicts_locks_its_output_before_the_analysis(tmp_path, monkeypatch, capsys):
    """``s2p conflicts`` locked only for its final write: two runs both computed."""
    import sys

    from hostile_fixtures import write_scene

    import seg2pose.safety.conflicts as SC
    from seg2pose.cli import main

    scene = write_scene(tmp_path / "scene", frames=4, users=2)
    (tmp_path / ".c.csv.lock").write_text(LockHolder(os.getppid(), socket.gethostname(),
                                                     utc_now()).to_json())

    def analyses(*a, **k):
        raise AssertionError("analysed although another process holds the output")

    monkeypatch.setattr(SC, "analyse", analyses)
    monkeypatch.setattr(sys, "argv", ["s2p", "conflicts", str(scene.gt_path), "-o", str(tmp_path / "c.csv"),
                                      "--fps", "10"])
    with pytest.raises(SystemExit) as e:
        main()
    assert e.value.code == 2
    assert "c.csv is being written by process" in capsys.readouterr().err
