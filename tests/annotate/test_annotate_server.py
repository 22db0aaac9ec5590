"""The annotation server is locked down: a random token per start is required for the page,
the API and the websocket; a Host or Origin that is not this server's loopback address is
refused; the log is opened without following links; SIGINT / SIGTERM stop it within 5 s and
release the edit lock. Unit tests of the Guard (no server) and one real server."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from annotate.app.guard import Guard

TOKEN = "t0ken-" + "x" * 20
PORT = 8123


def _call(scope_type="http", host=f"127.0.0.1:{PORT}", origin=None, query=b"", cookie=None,
          auth=None):
    """Run one request through Guard in front of an app that answers 200; returns (status or
    websocket close code, response headers, whether the app was reached)."""
    reached = []

    async def app(scope, receive, send):
        reached.append(scope["path"])
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    headers = [(b"host", host.encode())]
    for name, v in (("origin", origin), ("cookie", cookie), ("authorization", auth)):
        if v is not None:
            headers.append((name.encode(), v.encode()))
    scope = {"type": scope_type, "path": "/", "headers": headers, "query_string": query}
    sent = []

    async def receive():
        return {"type": "websocket.connect"} if scope_type == "websocket" else {"type": "http.request"}

    async def send(msg):
        sent.append(msg)

    asyncio.run(Guard(app, PORT, TOKEN)(scope, receive, send))
    first = sent[0]
    code = first.get("status", first.get("code"))
    return code, dict(first.get("headers", [])), bool(reached)


def test_guard_refuses_strangers_and_admits_the_token():
    q = f"access_token={TOKEN}".encode()
    assert _call(query=b"")[::2] == (403, False)                       # no token
    assert _call(query=b"access_token=guess")[::2] == (403, False)     # wrong token
    assert _call(host=f"evil.example:{PORT}", query=q)[::2] == (403, False)   # DNS rebinding
    assert _call(host="127.0.0.1:9999", query=q)[::2] == (403, False)  # another port
    assert _call(origin="http://evil.example", query=q)[::2] == (403, False)
    assert _call("websocket", origin="http://evil.example", query=q)[::2] == (1008, False)
    assert _call("websocket", query=b"")[::2] == (1008, False)
    # the token in the URL admits the request and sets the session cookie (a hash, not the token)
    code, headers, reached = _call(query=q, origin=f"http://localhost:{PORT}")
    assert code == 200 and reached
    cookie = headers[b"set-cookie"].decode()
    assert TOKEN not in cookie and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    jar = cookie.split(";")[0]
    assert _call("websocket", cookie=jar, origin=f"http://127.0.0.1:{PORT}")[::2] == (200, True)
    assert _call(cookie=jar.replace("=", "=0"))[::2] == (403, False)


def test_guard_refusals_name_the_command_serving_the_page():
    """The annotation server's refusal sends the user to `s2p annotate`'s URL; the calibration
    page's (the same Guard) to `s2p calibrate-camera`'s."""
    async def app(scope, receive, send):  # never reached
        raise AssertionError

    def refusal(guard, cookie=""):
        scope = {"type": "http", "path": "/", "query_string": b"",
                 "headers": [(b"host", f"127.0.0.1:{PORT}".encode()), (b"cookie", cookie.encode())]}
        return guard.refusal(scope)[0]

    annotate, calib = Guard(app, PORT, TOKEN), Guard(app, PORT, TOKEN, command="s2p calibrate-camera")
    assert "open the URL that `s2p annotate` printed" in refusal(annotate)
    assert "open the URL that `s2p calibrate-camera` printed" in refusal(calib)
    assert "annotate" not in refusal(calib)
    stale = f"{calib.cookie}={'x' * 64}"  # a cookie of an earlier start
    assert "earlier start of `s2p calibrate-camera`" in refusal(calib, stale)
    assert _call(auth=f"Bearer {TOKEN}")[::2] == (200, True)


def test_log_is_opened_without_following_links(tmp_path):
    from annotate.app.serve import open_log

    scene = tmp_path / "scene"
    (scene / "annotations").mkdir(parents=True)
    target = tmp_path / "victim.txt"
    target.write_text("precious\n")
    (scene / "annotations" / "server.log").symlink_to(target)
    fd, path = open_log(scene)
    os.write(fd, b"log line\n")
    os.close(fd)
    assert target.read_text() == "precious\n"  # the planted link was not followed
    assert path.parent != scene / "annotations" and (path.stat().st_mode & 0o077) == 0
    assert (path.parent.stat().st_mode & 0o077) == 0  # a private folder


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("server") / "scene"
    generate_scene(root, SynthOptions(preset="small", frames=3, seed=1, video=False, progress=False, workers=1))
    return root


@pytest.mark.parametrize("sig", [signal.SIGINT])
def test_s2p_annotate_refuses_strangers_and_stops_on_a_signal(scene_dir, sig):
    """`s2p annotate SCENE --no-browser` prints a URL with a token; without it (or with a
    foreign Host / Origin) the page, the API and the websocket are refused; a page's session
    takes the edit lock; SIGINT stops the server within 5 s and releases the lock."""
    pytest.importorskip("marimo", reason="marimo is not installed (pip install -e '.[app]')")
    import http.cookiejar
    import urllib.error
    import urllib.request

    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from annotate.app.serve import _port_open, free_port

    port = free_port()
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    proc = subprocess.Popen([sys.executable, "-c", "from seg2pose.cli import main; main()",
                             "annotate", str(scene_dir), "--no-browser", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        line = ""
        while "annotation app for" not in line:  # after the progress bar of the first open
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "s2p annotate printed no URL"
        assert f"{base}/?access_token=" in line, line
        url = line.split(" at ")[1].split()[0]

        def status(u, headers=None, data=None):
            req = urllib.request.Request(u, headers=headers or {}, data=data)
            try:
                with urllib.request.urlopen(req, timeout=30) as r:
                    return r.status
            except urllib.error.HTTPError as e:
                return e.code

        assert status(base + "/") == 403
        assert status(url, {"Host": f"evil.example:{port}"}) == 403
        assert status(url, {"Origin": "http://evil.example"}) == 403
        assert status(base + "/api/kernel/set_model_value", {"Content-Type": "application/json"},
                      b'{"action": "new_track"}') == 403
        for hdr in ({"Origin": "http://evil.example"}, {}):
            with pytest.raises(InvalidStatus, match="403"):
                connect(f"ws://127.0.0.1:{port}/ws?session_id=s1", additional_headers=hdr,
                        open_timeout=20)
        jar = http.cookiejar.CookieJar()
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(jar))
        with opener.open(url, timeout=30) as r:
            assert r.status == 200 and b"marimo" in r.read()
        cookie = "; ".join(f"{c.name}={c.value}" for c in jar)
        lock = scene_dir / "annotations" / "lock"
        with connect(f"ws://127.0.0.1:{port}/ws?session_id=s1", origin=base,
                     additional_headers={"Cookie": cookie}, open_timeout=60) as ws:
            t0 = time.monotonic()  # the page's session opens the project: the lock is taken
            while not (lock.exists() and lock.read_text().strip()) and time.monotonic() - t0 < 120:
                try:
                    ws.recv(timeout=0.5)
                except TimeoutError:
                    pass
            assert lock.read_text().strip(), "the page never opened the project"
            t0 = time.monotonic()
            proc.send_signal(sig)
            proc.wait(10)
            while _port_open(port) and time.monotonic() - t0 < 10:
                time.sleep(0.1)
            took = time.monotonic() - t0
        # the server gets SIGTERM, then SIGKILL after serve.STOP_SECONDS (4 s): 5 s on an idle
        # machine; a margin for a loaded one
        assert not _port_open(port) and took < 8.0, f"stopped after {took:.1f} s"
        assert lock.read_text().strip() == "", "the edit lock was not released"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
