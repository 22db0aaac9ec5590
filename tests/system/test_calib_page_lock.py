"""Issue 38: ``s2p calibrate-camera``'s clicking page (a real ``s2p`` process) holds the locks
of the outputs a Save writes from its start: a second page on the same output and a
``--points`` run into it are refused in one line while it is open; its own Save (pairs sent
to its API) writes through those locks; killed (SIGKILL), it leaves no partial output, a page
can start again at once, and the next writer takes over the dead one's lock files and leaves
none behind."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
from video_fixtures import H, W, write_folder

from seg2pose.geometry.camera import Camera

S2P = str(Path(sys.executable).with_name("s2p"))
# eight ground points in view of the camera below (a 2 x 4 grid on z = 0)
GRID = [(x, y) for y in (0.5, 4.0, 9.0, 18.0) for x in (-3.0, 3.0)]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _site(tmp_path: Path):
    cam = Camera.look_at("c0", np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 150.0, W, H)
    write_folder(tmp_path / "frames", 2, [])
    X = np.array([[x, y, 0.0] for x, y in GRID])
    uv = cam.project_points(X)[0]
    (tmp_path / "survey.csv").write_text("name,x,y,z\n" + "".join(
        f"s{i},{x},{y},0\n" for i, (x, y) in enumerate(GRID)))
    (tmp_path / "pairs.csv").write_text("camera,u,v,x,y,z\n" + "".join(
        f"c0,{u!r},{v!r},{x},{y},0\n" for (u, v), (x, y) in zip(uv.tolist(), GRID, strict=True)))
    return uv


def _page(tmp_path: Path, port: int, *more: str) -> subprocess.Popen:
    return subprocess.Popen([S2P, "calibrate-camera", tmp_path / "frames", "--survey", tmp_path / "survey.csv",
                             "-o", tmp_path / "cal" / "calib.json", "--no-browser", "--port", str(port), *more],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _url(p: subprocess.Popen, timeout: float = 120.0) -> str:
    """The page's URL from its first line (waits for the server)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([p.stdout], [], [], 1.0)
        if r:
            line = p.stdout.readline()
            if line.startswith("calibration page at "):
                return line.split()[-1]
        if p.poll() is not None:
            raise AssertionError(f"the page ended ({p.returncode}): {p.stderr.read()}")
    raise AssertionError("the page did not start")


def _call(url: str, path: str, data: dict | None = None) -> dict:
    base, _, token = url.partition("/?access_token=")
    req = urllib.request.Request(base + path, data=None if data is None else json.dumps(data).encode(),
                                 headers={"authorization": "Bearer " + token,
                                          "content-type": "application/json"})
    end = time.monotonic() + 30
    while True:  # uvicorn says it listens a moment after the line is printed
        try:
            with urllib.request.urlopen(req, timeout=60) as r:
                return json.loads(r.read())
        except ConnectionRefusedError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)
        except urllib.error.URLError as e:
            if not isinstance(e.reason, ConnectionRefusedError) or time.monotonic() > end:
                raise
            time.sleep(0.2)


def _run(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([S2P, *map(str, argv)], capture_output=True, text=True, timeout=300)


def _beside(cal: Path) -> list[str]:
    """What lies in the output folder but the outputs and the page's journal."""
    return sorted(p.name for p in cal.iterdir() if p.name.startswith("."))


def test_the_page_locks_its_outputs_from_the_start(tmp_path):
    uv = _site(tmp_path)
    cal = tmp_path / "cal"
    page = _page(tmp_path, _free_port())
    try:
        url = _url(page)
        # a second page on the same output: refused in one line (its journal is held)
        second = _page(tmp_path, _free_port())
        assert second.wait(120) != 0
        err = second.stderr.read().strip()
        assert len(err.splitlines()) == 1 and "calib.points.jsonl is open in process" in err, err
        # a --points run into the page's output: refused before it writes, in one line
        r = _run("calibrate-camera", tmp_path / "frames", "--points", tmp_path / "pairs.csv", "-o",
                 cal / "calib.json", "--force")
        assert r.returncode != 0
        line = r.stderr.strip()
        assert len(line.splitlines()) == 1 and "is being written by process" in line, r.stderr
        assert not (cal / "calib.json").exists()
        # the page's own Save goes through the locks it holds
        for i, (u, v) in enumerate(uv.tolist()):
            _call(url, "/api/pair", {"camera": "c0", "u": u, "v": v, "survey": f"s{i}"})
        _call(url, "/api/solve", {})
        lines = _call(url, "/api/save", {})["lines"]
        assert lines[0].startswith("written: ") and (cal / "calib.json").exists()
        saved = (cal / "calib.json").read_bytes()
        assert json.loads(saved)["cameras"][0]["name"] == "c0"
    finally:
        os.killpg(page.pid, signal.SIGKILL)  # killed: nothing flushed, no handler run
        page.wait(60)
    # no partial output; the Save's outputs whole; only the dead page's lock files beside them
    assert (cal / "calib.json").read_bytes() == saved
    assert [n for n in _beside(cal) if not n.endswith(".lock")] == []
    # a page starts again at once (the journal's kernel lock went with the process)...
    again = _page(tmp_path, _free_port(), "--force")  # calib.json is there now
    try:
        assert _call(_url(again), "/api/state")["cameras"] == {"c0": [W, H]}
    finally:
        again.send_signal(signal.SIGINT)
        code = again.wait(60)
    assert code == 0, (code, again.stderr.read())  # Ctrl-C is how a page is stopped
    # ...and the next writer takes the dead page's locks over and leaves nothing beside
    r = _run("calibrate-camera", tmp_path / "frames", "--points", tmp_path / "pairs.csv", "-o",
             cal / "calib.json", "--force")
    assert r.returncode == 0, r.stderr
    assert [n for n in _beside(cal) if n != ".calib.points.jsonl.lock"] == []
