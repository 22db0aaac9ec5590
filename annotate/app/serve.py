"""Serve the annotation page: the server process (server.py: marimo behind the Guard) as a
child on a loopback port, with a random token per start.

The child gets its arguments in S2P_ANNOTATE_ARGS (JSON) and the token in S2P_ANNOTATE_TOKEN;
the page loads the viewer widget from the same server (server.ViewerAssets: the JavaScript and
Wasm of the installed rerun-notebook package, never the internet). ``Server`` starts it in its
own process group and stops the whole group. Its log goes to SCENE/annotations/server.log (else a private temporary
folder), opened without following links.

From another machine, reach the app through an SSH tunnel (never by binding another address):
``ssh -N -L PORT:127.0.0.1:PORT user@host`` (the same port on both ends: the page names it),
then open the printed URL.
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

from annotate.app.guard import TOKEN_PARAM, new_token
from annotate.app.server import ARGS_ENV, TOKEN_ENV
from seg2pose.core.errors import S2PError
from seg2pose.io.nofollow import open_nofollow

LOG_NAME = "server.log"
# SCENE/annotations/server.json (owner-only): the last start's port and token. A restart on the
# same port with the same token keeps an open tab working (its cookie and URL stay valid).
SERVER_FILE = "server.json"
STOP_SECONDS = 4.0  # SIGTERM, then SIGKILL after this long: stopped within 5 s


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
    token: str
    log: Path | None = None

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def url(self) -> str:
        """The page's address with the access token (what the annotator opens)."""
        return f"{self.base}/?{TOKEN_PARAM}={self.token}"

    def stop(self, timeout: float = STOP_SECONDS) -> None:
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


def die_with_parent() -> None:
    """In a child between fork and exec (``preexec_fn``): the kernel sends it SIGTERM when
    the process that started it ends, however it ends (Linux ``prctl(PR_SET_PDEATHSIG)``; a
    SIGKILLed ``s2p annotate`` left its server listening). Elsewhere: nothing."""
    import ctypes

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def open_log(scene: Path) -> tuple[int, Path]:
    """(fd, path) of the server's log: SCENE/annotations/server.log, else a file in a fresh
    private temporary folder; opened for appending without following a link, owner-only."""
    import tempfile

    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT
    folder = Path(scene) / "annotations"
    try:
        folder.mkdir(exist_ok=True)
        path = folder / LOG_NAME
        return open_nofollow(path, flags, 0o600), path
    except (OSError, S2PError):  # a linked annotations/ or log is refused (S2PError)
        path = Path(tempfile.mkdtemp(prefix="s2p-annotate-")) / LOG_NAME  # mode 0700
        return open_nofollow(path, flags | os.O_EXCL, 0o600), path


def pick_port_token(scene: Path, port: int | None) -> tuple[int, str]:
    """(port, token) of a start: the last start's (``SERVER_FILE``) when its port is free and
    no other port is asked for, so that a restart keeps the open tab working; else the asked
    (or a free) port and a new token."""
    import json

    last = Path(scene) / "annotations" / SERVER_FILE
    try:
        d = json.loads(last.read_text(encoding="utf-8")) if not last.is_symlink() else {}
        old_port, old_token = int(d["port"]), str(d["token"])
    except (OSError, ValueError, KeyError, TypeError):
        old_port, old_token = None, None
    if old_port is not None and old_token and len(old_token) >= 32 and port in (None, old_port) \
            and not _port_open(old_port):
        return old_port, old_token
    return port or free_port(), new_token()


def remember(scene: Path, port: int, token: str) -> None:
    """Keep this start's port and token for the next (``SERVER_FILE``, owner-only); a scene
    folder that cannot be written keeps nothing."""
    import json

    try:  # owner-only, never through a link; a torn file is no start to reuse (a new token)
        fd = open_nofollow(Path(scene) / "annotations" / SERVER_FILE,
                           os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    except (OSError, S2PError):
        return
    try:
        os.fchmod(fd, 0o600)  # a file left by an older start with wider rights
        os.write(fd, json.dumps({"port": port, "token": token}).encode())
    finally:
        os.close(fd)


def start(scene: Path, run: Path | None = None, cameras: list[str] | None = None,
          port: int | None = None, native: bool = False, log: Path | None = None,
          wait: float = 60.0) -> Server:
    """Start the page's server and wait until it listens. log: a file for the server's output
    (default: SCENE/annotations/server.log, see ``open_log``). Raises S2PError when it does not
    come up."""
    port, token = pick_port_token(Path(scene), port)
    if _port_open(port):
        raise S2PError(f"port {port} is in use; choose another with --port")
    env = dict(os.environ)
    env["RERUN_NOTEBOOK_ASSET"] = "serve-local"
    env[ARGS_ENV] = json.dumps({
        "scene": str(Path(scene).resolve()), "run": None if run is None else str(Path(run).resolve()),
        "cameras": list(cameras) if cameras else None, "native": native, "port": port})
    env[TOKEN_ENV] = token
    # the page imports s2p's packages: make this checkout importable in the child as it is here
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    cmd = [sys.executable, "-m", "annotate.app.server"]
    if log is None:
        fd, log = open_log(Path(scene))
    else:
        fd = open_nofollow(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
    try:
        proc = subprocess.Popen(cmd, env=env, stdout=fd, stderr=subprocess.STDOUT,
                                start_new_session=True, preexec_fn=die_with_parent)
    finally:
        os.close(fd)
    server = Server(proc, port, token, log)
    atexit.register(server.stop)  # whatever happens to this process, the server goes with it
    t0 = time.monotonic()
    while not _port_open(port):
        if proc.poll() is not None:
            raise S2PError(f"the annotation server exited with code {proc.returncode}; see {log}")
        if time.monotonic() - t0 > wait:
            server.stop()
            raise S2PError(f"the annotation server did not start within {wait:.0f} s")
        time.sleep(0.2)
    remember(Path(scene), port, token)
    return server


def run_app(scene: Path, run: Path | None = None, cameras: list[str] | None = None,
            port: int | None = None, browser: bool = True, native: bool = False,
            echo=print) -> None:
    """``s2p annotate SCENE``: check the input, start the server, print its URL, open the
    browser, and serve until interrupted (then stop the server and what it started)."""
    import webbrowser

    check_scene(scene, run, cameras)
    from annotate.app.viewer_cache import prepare_viewer

    prepare_viewer(scene, run, cameras)  # videos encoded once, here with a progress bar
    # the server runs in its own process group (so that stopping it stops all it started):
    # SIGINT and SIGTERM to this process stop it (SIGINT too where a shell started us in the
    # background with SIGINT ignored)
    for sig, code in ((signal.SIGTERM, 143), (signal.SIGINT, 130)):
        signal.signal(sig, lambda *_, c=code: sys.exit(c))
    server = start(scene, run, cameras, port=port, native=native)
    echo(f"annotation app for {scene} at {server.url}\n  (only this machine can reach it; from "
         f"another one use an SSH tunnel: ssh -N -L {server.port}:127.0.0.1:{server.port} "
         f"USER@THIS-HOST, then open the same URL there. Ctrl-C stops it; server log: "
         f"{server.log})")
    if browser:
        webbrowser.open(server.url)
    try:
        code = server.proc.wait()
    finally:
        server.stop()
    if code != 0:  # it died on its own (a stop by Ctrl-C or SIGTERM exits this process first)
        raise S2PError(f"the annotation server stopped with exit code {code}: "
                       f"{_last_line(server.log)} (log: {server.log})")
    raise S2PError(f"the annotation server stopped unexpectedly (log: {server.log})")


def _last_line(log: Path | None) -> str:
    """The last non-empty line of the server's log (why it stopped), or a placeholder."""
    try:
        with open(log, "rb") as f:  # type: ignore[arg-type]
            f.seek(0, 2)
            f.seek(max(0, f.tell() - 4096))
            lines = [ln.strip() for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]
        return lines[-1] if lines else "its log is empty"
    except (OSError, TypeError):
        return "no log"
