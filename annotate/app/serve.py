"""Serve the annotation page: ``marimo run notebook.py`` as a child process on a local port.

The child gets its arguments in S2P_ANNOTATE_ARGS (JSON) and RERUN_NOTEBOOK_ASSET=serve-local
(the viewer's JavaScript and Wasm come from the installed rerun-notebook package, never the
internet). ``Server`` starts it in its own process group and stops the whole group.
"""

from __future__ import annotations

import atexit
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from seg2pose.core.errors import S2PError

NOTEBOOK = Path(__file__).with_name("notebook.py")
SESSION_TTL = 5  # seconds marimo keeps a page's session after its tab is gone


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


@dataclass
class Server:
    """A running ``marimo run`` of the annotation page."""

    proc: subprocess.Popen
    port: int
    log: Path | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the server and everything it started (its process group)."""
        if self.proc.poll() is not None:
            return
        try:
            os.killpg(self.proc.pid, signal.SIGTERM)
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout)
        except ProcessLookupError:
            pass


def check_scene(scene: Path, run: Path | None, cameras: list[str] | None) -> None:
    """Refuse bad input before the server starts (one-line errors): an unreadable scene, a
    run of another scene, unknown cameras."""
    from seg2pose.io.scene import load_scene

    s = load_scene(scene)
    if cameras:
        unknown = [c for c in cameras if c not in s.cameras]
        if unknown:
            raise S2PError(f"unknown cameras {unknown}; the scene has {sorted(s.cameras)}")
    if run is not None:
        from annotate.estimates import RunEstimates

        RunEstimates.load(run, s)  # refuses a run made on another scene (fingerprint)


def start(scene: Path, run: Path | None = None, cameras: list[str] | None = None,
          port: int | None = None, native: bool = False, log: Path | None = None,
          wait: float = 60.0) -> Server:
    """Start the page's server and wait until it listens. log: a file for the server's output
    (default: inherit this process's). Raises S2PError when it does not come up."""
    port = port or free_port()
    if _port_open(port):
        raise S2PError(f"port {port} is in use; choose another with --port")
    env = dict(os.environ)
    env["RERUN_NOTEBOOK_ASSET"] = "serve-local"
    env["S2P_ANNOTATE_ARGS"] = json.dumps({
        "scene": str(Path(scene).resolve()), "run": None if run is None else str(Path(run).resolve()),
        "cameras": list(cameras) if cameras else None, "native": native})
    # the page imports s2p's packages: make this checkout importable in the child as it is here
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    cmd = [sys.executable, "-m", "marimo", "run", str(NOTEBOOK), "--headless", "--port", str(port),
           "--host", "127.0.0.1", "--no-token", "--session-ttl", str(SESSION_TTL), "--no-sandbox"]
    out = open(log, "ab") if log is not None else None
    proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT if out else None,
                            start_new_session=True)
    if out is not None:
        out.close()
    server = Server(proc, port, log)
    atexit.register(server.stop)  # whatever happens to this process, the server goes with it
    t0 = time.monotonic()
    while not _port_open(port):
        if proc.poll() is not None:
            raise S2PError(f"the annotation server exited with code {proc.returncode}"
                           + (f"; see {log}" if log else ""))
        if time.monotonic() - t0 > wait:
            server.stop()
            raise S2PError(f"the annotation server did not start within {wait:.0f} s")
        time.sleep(0.2)
    return server


def run_app(scene: Path, run: Path | None = None, cameras: list[str] | None = None,
            port: int | None = None, browser: bool = True, native: bool = False,
            echo=print) -> None:
    """``s2p annotate SCENE``: check the input, start the server, print its URL, open the
    browser, and serve until interrupted (then stop the server and what it started)."""
    import webbrowser

    check_scene(scene, run, cameras)
    # the server runs in its own process group (so that stopping it stops all it started):
    # a SIGTERM to this process must still stop it, like Ctrl-C does
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    import tempfile

    port = port or free_port()
    log = Path(tempfile.gettempdir()) / f"s2p-annotate-{port}.log"
    server = start(scene, run, cameras, port=port, native=native, log=log)
    echo(f"annotation app for {scene} at {server.url}  (Ctrl-C to stop; server log: {log})")
    if browser:
        webbrowser.open(server.url)
    try:
        server.proc.wait()
    finally:
        server.stop()
