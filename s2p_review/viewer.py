"""Viewer control with ``rerun.experimental.ViewerClient``: spawn (desktop or headless) or
connect, follow and set the time cursor, wait for a recording to load, take screenshots.

The headless viewer renders with whatever Vulkan adapter exists; on a machine without a GPU
that is Mesa's software rasteriser (Debian: ``mesa-vulkan-drivers``). It needs an
``XDG_RUNTIME_DIR``; we make a private one when none is set.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import urlparse

from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_write_bytes, check_writable, holding


class ViewerError(S2PError):
    """The viewer could not be started, reached or driven."""


def rerun_executable() -> str:
    """The ``rerun`` command of this Python environment (the venv's bin is often not on PATH)."""
    cand = Path(sys.executable).parent / "rerun"
    if cand.exists():
        return str(cand)
    found = shutil.which("rerun")
    if found is None:
        raise ViewerError("the `rerun` viewer executable was not found (install rerun-sdk)")
    return found


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def vulkan_problem() -> str | None:
    """Why a viewer cannot render here, or None when a Vulkan driver seems present."""
    import ctypes.util

    if ctypes.util.find_library("vulkan") is None:
        return ("no Vulkan loader (libvulkan.so.1; on Debian/Ubuntu: apt-get install libvulkan1 "
                "mesa-vulkan-drivers, or `make viewer-deps` as root)")
    icd_dirs = [Path("/usr/share/vulkan/icd.d"), Path("/etc/vulkan/icd.d")]
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return None
    if any(d.is_dir() and any(d.glob("*.json")) for d in icd_dirs):
        return None
    return ("no Vulkan driver found (on Debian/Ubuntu: apt-get install mesa-vulkan-drivers, "
            "or `make viewer-deps` as root)")


def _ensure_runtime_dir() -> None:
    d = os.environ.get("XDG_RUNTIME_DIR")
    if not d or not os.path.isdir(d):
        os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="s2p-xdg-")
        _made_runtime_dir.append(os.environ["XDG_RUNTIME_DIR"])  # the viewer's guard removes it


def check_reachable(url: str, timeout: float = 2.0) -> None:
    """Raise ViewerError unless ``url`` (rerun+http://host:port/proxy) accepts connections."""
    u = urlparse(url)
    if u.scheme not in ("rerun", "rerun+http", "rerun+https") or not u.hostname:
        raise ViewerError(f"bad viewer URL {url!r}; expected rerun+http://HOST:PORT/proxy")
    port = u.port or (443 if u.scheme == "rerun+https" else 9876)
    try:
        with socket.create_connection((u.hostname, port), timeout=timeout):
            pass
    except OSError as e:
        raise ViewerError(f"no viewer answers at {url} ({e.strerror or e}); start one with "
                          f"`rerun` or use --spawn") from None


def spawn_viewer(headless: bool, port: int | None = None, timeout: float = 30.0):
    """Start a viewer (native window, or headless) and return its ViewerClient once it answers.
    The caller stops it with ``stop``; a desktop viewer is detached and outlives us."""
    from rerun.experimental import ViewerClient

    if headless:
        problem = vulkan_problem()
        if problem:
            raise ViewerError(f"cannot run a headless viewer: {problem}")
        _ensure_runtime_dir()
    elif sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or
                                                   os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerError("no display to open the viewer on (DISPLAY / WAYLAND_DISPLAY unset); "
                          "write a recording (.rrd) and open it with `rerun FILE.rrd` where there is "
                          "one, or take a headless screenshot")
    port = port or free_port()
    saved = {k: os.environ.get(k) for k in ("XDG_DATA_HOME", "XDG_CONFIG_HOME")}
    if headless:  # a throw-away viewer must not read or write the user's saved layouts
        state = tempfile.mkdtemp(prefix="s2p-viewer-state-")
        os.environ["XDG_DATA_HOME"] = os.path.join(state, "data")
        os.environ["XDG_CONFIG_HOME"] = os.path.join(state, "config")
    else:
        state = None
    # a headless viewer ends with this process, however it ends: its guard starts first, so
    # that a kill while the viewer starts (before its pid is known) leaves nothing either
    guard = _guard(port, state) if headless else None
    try:
        client = ViewerClient.spawn(headless=headless, port=port, hide_welcome_screen=True,
                                    executable_path=rerun_executable(),
                                    detach_process=not headless)
        if guard is not None:
            _guards[getattr(client, "_pid", None) or -port] = guard
    except (ConnectionError, RuntimeError, OSError) as e:
        if guard is not None:
            os.close(guard)  # the guard removes what the failed start left
        if state:
            shutil.rmtree(state, ignore_errors=True)
        raise ViewerError(f"the viewer did not start on port {port}: {e}") from None
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    deadline = time.monotonic() + timeout
    while True:
        try:
            client.get_state()
            if guard is not None:  # the guard notes the viewer's processes (see _GUARD)
                with contextlib.suppress(OSError):
                    os.write(guard, b"answers\n")
            return client
        except Exception as e:  # noqa: BLE001 - still starting: connection refused etc.
            if time.monotonic() > deadline:
                stop(client)
                raise ViewerError(f"the viewer did not answer on port {port} within {timeout:.0f} s: {e}") from None
            time.sleep(0.2)


# The guard of a headless viewer: a small Python that waits for this process to end or to stop
# the viewer (the pipe it reads closes however this process ends, SIGKILL included), then kills
# the viewer and removes what it leaves: its state folder, Rerun's rerun-data-PID-* folders and
# the runtime folder s2p made for it. Rerun starts the viewer itself (in a process group of its
# launcher's), so it cannot be given a parent-death signal, and the guard starts before it:
# the viewer is found by its command line (--port=PORT --headless), also one whose start a kill
# cut short. Without the guard a killed ``s2p screenshot`` left ~700 MB running.
_GUARD = r"""
import glob, os, shutil, signal, sys, time
port, state, tmp, xdg = sys.argv[1:5]

def viewers():
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/cmdline", "rb") as f:
                    argv = f.read().split(b"\0")
            except OSError:
                continue
            if f"--port={port}".encode() in argv and b"--headless" in argv:
                out.append(int(d))
    return out

seen = set()
for _ in sys.stdin.buffer:  # "answers": the viewer runs; note its processes (they may quit first)
    seen.update(viewers())
for i in range(20):  # a launcher that was starting its viewer: look again for a while
    found = viewers()
    seen.update(found)
    for pid in found:
        try:
            os.killpg(pid, signal.SIGKILL) if os.getpgid(pid) == pid else os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    if not found and i >= 3:
        break
    time.sleep(0.1)
for pid in seen:
    for d in glob.glob(os.path.join(tmp, f"rerun-data-{pid}-*")):
        shutil.rmtree(d, ignore_errors=True)
for d in (state, xdg):
    if d:
        shutil.rmtree(d, ignore_errors=True)
"""
_guards: dict[int, int] = {}  # viewer pid -> the write end of its guard's pipe
_made_runtime_dir: list[str] = []  # the XDG_RUNTIME_DIR s2p made (its guard removes it)


def _guard(port: int, state: str | None) -> int:
    """Start the guard of the headless viewer on ``port`` and its state folder (see
    ``_GUARD``); the write end of its pipe (closed: the guard does its work)."""
    import subprocess

    r, w = os.pipe()  # both ends close on exec: only the guard gets ``r``, as its stdin
    try:
        subprocess.Popen([sys.executable, "-c", _GUARD, str(port), state or "", tempfile.gettempdir(),
                          _made_runtime_dir[-1] if _made_runtime_dir else ""], stdin=r,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    finally:
        os.close(r)
    return w


def connect_viewer(url: str):
    from rerun.experimental import ViewerClient

    check_reachable(url)
    return ViewerClient.connect(url)


def stop(client) -> None:
    """Quit a viewer this process spawned (no-op for connected ones)."""
    pid = getattr(client, "_pid", None)
    if pid is not None:
        try:
            client.quit(timeout=5.0)
        except RuntimeError:
            pass
        w = _guards.pop(pid, None)
        if w is not None:  # the guard kills what is left and removes the state folder
            os.close(w)


def wait_loaded(client, timeline: str = "frame", min_end: int | None = None, timeout: float = 60.0):
    """Poll until the active recording has ``timeline`` (reaching ``min_end`` when given) and
    nothing is loading; returns the ViewerState."""
    deadline = time.monotonic() + timeout
    while True:
        st = client.get_state()
        rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
        tl = None if rec is None else next((t for t in rec.timelines if t.name == timeline), None)
        if tl is not None and not st.loading and (min_end is None or (tl.end is not None and tl.end >= min_end)):
            return st
        if time.monotonic() > deadline:
            raise ViewerError(f"the viewer did not finish loading within {timeout:.0f} s "
                              f"(loading: {[s.status for s in st.loading]})")
        time.sleep(0.25)


def follow(client, timeline: str = "frame") -> None:
    """Make the viewer follow the newest data on ``timeline`` (live review of a running job)."""
    client.set_time(timeline, play_state="following")


def set_frame(client, frame: int, timeline: str = "frame") -> None:
    client.set_time(timeline, sequence=int(frame), play_state="paused")


def view_reports(client) -> list[tuple[str, str, str]]:
    """(view name, severity, summary) for every view that reports a warning or an error."""
    st = client.get_state()
    return [(v.name, r.severity, r.summary) for v in st.views for r in v.reports]


def screenshot_when_loaded(client, png: Path, frame: int | None = None, force: bool = False,
                           settle: float = 1.5, max_size: int | None = None,
                           min_end: int | None = None, timeline: str = "frame") -> bytes:
    """Wait for the recording, put the cursor on ``frame``, let it paint, save a PNG atomically."""
    png = Path(png)
    wait_loaded(client, timeline=timeline, min_end=frame if min_end is None else min_end)
    if frame is not None:
        set_frame(client, frame)
    time.sleep(settle)  # the software rasteriser needs a few frames to upload and paint
    data = client.take_screenshot(max_size=max_size)
    if not data:
        raise ViewerError("the viewer returned an empty screenshot")
    check_writable(png, force)
    atomic_write_bytes(png, data)
    return data


MCAP_TIMELINE = "message_log_time"  # the timeline Rerun's MCAP loader makes of log times


def _mcap_time(source: Path, frame: int | None) -> int | None:
    """The log time (ns) of ``frame`` in an ``s2p export`` file (its metadata record ``s2p``:
    start_ns, fps); None for the middle of the file or a file without that record."""
    if frame is None:
        return None
    from mcap.reader import make_reader

    with open(source, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}.get("s2p")
    if not meta or "fps" not in meta:
        raise S2PError(f"{source}: not an `s2p export` file, so frame {frame} has no known time; "
                       "leave the frame out to take the middle of the file")
    return int(meta.get("start_ns", 0)) + int(round(frame * 1e9 / float(meta["fps"])))


def take_screenshot(source: Path | str, png_path: Path, *, frame: int | None = None,
                    force: bool = False, max_size: int | None = None) -> Path:
    """Open a recording (.rrd) or an MCAP export (.mcap; Rerun lays it out by itself and draws
    its images, camera calibrations and poses, not its scene updates or image annotations) in a
    fresh headless viewer and save a screenshot of it (the README picture). ``frame``: where to
    put the time cursor (default: the middle)."""
    source = Path(source)
    if not source.exists():
        raise S2PError(f"{source}: recording not found")
    with holding(png_path):  # from the start: a second screenshot of the same PNG is refused
        check_writable(Path(png_path), force)
        return _take_screenshot(source, Path(png_path), frame, force, max_size)


def _take_screenshot(source: Path, png_path: Path, frame: int | None, force: bool,
                     max_size: int | None) -> Path:
    import numpy as np

    mcap = source.suffix.lower() == ".mcap"
    timeline = MCAP_TIMELINE if mcap else "frame"
    at = _mcap_time(source, frame) if mcap else frame
    client = spawn_viewer(headless=True)
    try:
        client.open(str(source.resolve()))
        st = wait_loaded(client, timeline=timeline)
        if at is None:
            rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
            tl = next((t for t in rec.timelines if t.name == timeline), None) if rec else None
            if tl is not None and tl.start is not None and tl.end is not None:
                at = (tl.start + tl.end) // 2
        if mcap and at is not None:
            client.set_time(timeline, timestamp=np.datetime64(int(at), "ns"), play_state="paused")
            at = None
        screenshot_when_loaded(client, Path(png_path), frame=at, force=force, max_size=max_size,
                               timeline=timeline)
    finally:
        stop(client)
    return Path(png_path)
