"""The calibration page's state without a browser (annotate/app/calib_state.py, calib_serve.py):
pairs from the aerial image and the survey table, undo, the journal replayed after a crash
(a torn last line kept aside), one writer at a time, and the gate in front of the API."""

from __future__ import annotations

import json

import numpy as np
import pytest

from annotate.app.calib_serve import PageArgs, build_app, open_state
from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.calib_files import write_world_file
from seg2pose.io.jsonl_log import read_log


@pytest.fixture()
def args(tmp_path):
    (tmp_path / "aerial.png").write_bytes(b"not read by the state")
    write_world_file(tmp_path / "aerial.pgw", np.array([[0.05, 0.0, -10.0], [0.0, -0.05, 20.0]]))
    (tmp_path / "survey.csv").write_text("name,x,y,z\nkerb,3,4,0.15\npole,5,6,\n")
    return PageArgs(source=None, aerial=tmp_path / "aerial.png", world_file=None, reference=[],
                    survey=tmp_path / "survey.csv", cameras=["c0"], sizes={"*": (640, 480)},
                    out=tmp_path / "out" / "calib.json", devices=None)


def test_pairs_undo_and_replay(args, tmp_path):
    state, scene = open_state(args)
    assert scene is None
    a = state.add_pair("c0", 10, 20, ax=200, ay=100)  # the world file: x = 0.05 u - 10, y = 20 - 0.05 v
    assert (a["x"], a["y"], a["z"]) == pytest.approx((0.0, 15.0, None))
    b = state.add_pair("c0", 30, 40, survey="kerb")
    assert (b["x"], b["y"], b["z"]) == (3.0, 4.0, 0.15)
    c = state.add_pair("c0", 50, 60, survey="pole", z=0.5)
    assert c["z"] == 0.5
    state.undo()
    assert [p["name"] for p in state.pairs()] == ["p1", "kerb"]
    with pytest.raises(InputError, match="outside the 640x480 frame"):
        state.add_pair("c0", 700, 20, ax=1, ay=1)
    with pytest.raises(S2PError, match="is open in process"):
        open_state(args)  # one writer at a time
    # a crash in the middle of the next record: the torn line is skipped and kept aside
    journal = args.out.with_name("calib.points.jsonl")
    with open(journal, "ab") as f:
        f.write(b'{"kind":"pair","id":9,"cam')
    state.close()
    state2, _ = open_state(args)
    try:
        assert [p["name"] for p in state2.pairs()] == ["p1", "kerb"]
        assert "torn" in state2.log.note
        assert len(list(tmp_path.glob("out/calib.points.jsonl.torn-*"))) == 1
        records, _, note = read_log(journal)
        assert note is None and records[-1] == {"kind": "undo", "of": 3}
        arr = state2.pair_arrays()["c0"]
        np.testing.assert_allclose(arr["uv"], [[10, 20], [30, 40]])
        assert np.isnan(arr["X"][0, 2]) and arr["X"][1, 2] == 0.15
    finally:
        state2.close()


def call(app, method: str, path: str, headers: dict | None = None, body: bytes = b"") -> tuple[int, bytes]:
    """One HTTP request through the ASGI app (no client library): (status, body)."""
    import asyncio

    path, _, query = path.partition("?")
    hdrs = [(b"host", b"127.0.0.1:8999")] + [(k.encode(), v.encode()) for k, v in (headers or {}).items()]
    scope = {"type": "http", "method": method, "path": path, "raw_path": path.encode(),
             "query_string": query.encode(), "headers": hdrs, "scheme": "http", "http_version": "1.1",
             "server": ("127.0.0.1", 8999), "client": ("127.0.0.1", 1234), "root_path": ""}
    sent = [{"type": "http.request", "body": body, "more_body": False}]
    out = {"status": 0, "body": b""}

    async def receive():
        return sent.pop(0) if sent else {"type": "http.disconnect"}

    async def send(msg):
        if msg["type"] == "http.response.start":
            out["status"] = msg["status"]
        elif msg["type"] == "http.response.body":
            out["body"] += msg.get("body", b"")

    asyncio.run(app(scope, receive, send))
    return out["status"], out["body"]


def test_the_gate(args):
    state, scene = open_state(args)
    tok = "t" * 32
    try:
        app = build_app(state, scene, 8999, tok)
        code, body = call(app, "GET", "/api/state")  # no token: the refusal names this page's command
        assert code == 403 and b"`s2p calibrate-camera` printed" in body and b"annotate" not in body
        code, body = call(app, "GET", "/api/state?access_token=" + tok)
        assert code == 200 and json.loads(body)["cameras"] == {"c0": [640, 480]}
        hdr = {"authorization": "Bearer " + tok}
        pair = json.dumps({"camera": "c0", "u": 1, "v": 2, "ax": 3, "ay": 4}).encode()
        code, _ = call(app, "POST", "/api/pair", {**hdr, "origin": "http://evil.example"}, pair)
        assert code == 403 and not state.pairs()
        code, body = call(app, "POST", "/api/pair", hdr, json.dumps({"camera": "c0", "u": 1, "v": "x"}).encode())
        assert code == 400 and "v must be a number" in json.loads(body)["error"]
        code, body = call(app, "POST", "/api/solve", hdr, b"{}")
        assert code == 400 and "no pairs yet" in json.loads(body)["error"]
        code, body = call(app, "POST", "/api/pair", hdr, pair)
        assert code == 200 and len(state.pairs()) == 1
    finally:
        state.close()
