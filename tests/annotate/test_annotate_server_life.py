"""The annotation server's life: every page it admits may reach this server only (CSP), a tab
of an earlier start is told so in one line, and `s2p annotate` exits non-zero with the log's
last line when its server dies."""

from __future__ import annotations

import subprocess
import sys

import pytest
from test_annotate_server import PORT, TOKEN, _call

from seg2pose.core.errors import S2PError


def test_pages_may_reach_this_server_only():
    code, headers, reached = _call(query=f"access_token={TOKEN}".encode())
    assert code == 200 and reached
    csp = headers[b"content-security-policy"].decode()
    assert csp.startswith("connect-src 'self' ") and f"ws://127.0.0.1:{PORT}" in csp
    assert "https:" not in csp and "*" not in csp
    # a cookie of this port from an earlier start (another token): one line saying so
    code, headers, reached = _call(cookie=f"s2p_annotate_{PORT}=stale")
    assert code == 403 and not reached


def test_s2p_annotate_exits_with_the_reason_when_its_server_dies(tmp_path, monkeypatch):
    from annotate.app import serve

    log = tmp_path / "server.log"
    with open(log, "w") as f:  # a stand-in server writes its own log (a test, not the library)
        proc = subprocess.Popen([sys.executable, "-c", "print('2026-01-01 boom: port gone');"
                                 "import sys; sys.exit(3)"], stdout=f)
    monkeypatch.setattr(serve, "check_scene", lambda *a: None)
    monkeypatch.setattr(serve, "start", lambda *a, **k: serve.Server(proc, PORT, TOKEN, log))
    import annotate.app.viewer_cache as viewer_cache

    monkeypatch.setattr(viewer_cache, "prepare_viewer", lambda *a: None)
    said = []
    with pytest.raises(S2PError, match="stopped with exit code 3: 2026-01-01 boom: port gone"):
        serve.run_app(tmp_path, browser=False, echo=said.append)
    assert said and "annotation app for" in said[0]


def test_a_restart_keeps_the_port_and_token_so_an_open_tab_goes_on(tmp_path):
    import os
    import socket

    from annotate.app.serve import SERVER_FILE, pick_port_token, remember

    (tmp_path / "annotations").mkdir()
    port, token = pick_port_token(tmp_path, None)       # nothing remembered: new ones
    remember(tmp_path, port, token)
    assert os.stat(tmp_path / "annotations" / SERVER_FILE).st_mode & 0o077 == 0  # owner-only
    assert pick_port_token(tmp_path, None) == (port, token)      # the restart: the same
    assert pick_port_token(tmp_path, port) == (port, token)
    other = pick_port_token(tmp_path, port + 1)                  # another port asked for
    assert other[0] == port + 1 and other[1] != token
    with socket.socket() as s:                                    # the old port taken meanwhile
        s.bind(("127.0.0.1", port))
        s.listen()
        p2, t2 = pick_port_token(tmp_path, None)
        assert p2 != port and t2 != token
