"""seg2pose.io.run: the run folder's one owner (views table round trip, the folder written as a
unit, one writer at a time, paths relative to the run folder)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable, format_views, read_run, read_views, relative_path, run_lock, write_run_folder


def views(n: int = 5, seed: int = 0) -> ViewTable:
    rng = np.random.default_rng(seed)
    normal = rng.normal(0, 20, (n, 3))
    normal[1] = np.nan  # a missed ray
    return ViewTable(rng.integers(0, 9, n), rng.integers(-1, 4, n),
                     rng.choice(["c0", "c1"], n), rng.choice(["car", "pedestrian"], n),
                     rng.uniform(0, 960, (n, 2)), normal, rng.normal(0, 0.3, (n, 2)))


def poses(n: int = 3) -> PoseTable:
    return PoseTable(np.arange(n), np.arange(n), np.array(["car"] * n, object),
                     np.c_[np.arange(n) * 1.5, -np.arange(n) / 3, np.zeros(n)], np.full(n, 0.25),
                     np.tile([4.5, 1.8, 1.5], (n, 1)))


def assert_views_equal(a: ViewTable, b: ViewTable) -> None:
    for col in ("frame", "track_id", "camera", "cls", "uv", "normal", "residual"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))


def test_views_round_trip_exact(tmp_path):
    v = views(40)
    write_run_folder(tmp_path / "run", poses(), v, {"method": "baseline"})
    back = read_views(tmp_path / "run" / "views.csv")
    assert_views_equal(back, v)  # floats with repr: bit-exact, NaN included, table order kept
    assert format_views(back) == (tmp_path / "run" / "views.csv").read_text()


def test_views_known_text():
    v = ViewTable([3], [7], ["c1"], ["car"], [[10.5, 20.0]], [[1.0, -2.0, 0.5]], [[0.1, -0.2]])
    assert format_views(v) == ("frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy\n"
                               "3,7,c1,car,10.5,20.0,1.0,-2.0,0.5,0.1,-0.2\n")


def test_view_table_sorted_and_of_cameras():
    v = ViewTable([2, 1, 1, 1], [0, 5, 2, 2], ["c0", "c0", "c1", "c0"], ["car"] * 4,
                  np.zeros((4, 2)), np.zeros((4, 3)), np.zeros((4, 2)))
    s = v.sorted()
    assert list(zip(s.frame, s.track_id, s.camera)) == [(1, 2, "c0"), (1, 2, "c1"), (1, 5, "c0"),
                                                        (2, 0, "c0")]
    assert list(v.of_cameras(["c1"]).frame) == [1]
    assert len(ViewTable.concat([v, v])) == 8 and len(ViewTable.empty()) == 0
    with pytest.raises(ValueError, match="length"):
        ViewTable([1, 2], [1], ["c0"], ["car"], np.zeros((1, 2)), np.zeros((1, 3)), np.zeros((1, 2)))


def test_read_run_reads_all_three(tmp_path):
    v, p = views(), poses()
    meta = {"method": "seg2posenet", "cameras": ["c0", "c1"]}
    write_run_folder(tmp_path / "r", p, v, meta)
    run = read_run(tmp_path / "r")
    assert run.meta == meta
    np.testing.assert_array_equal(run.poses.xyz, p.xyz)
    assert_views_equal(run.views, v)
    (tmp_path / "r" / "run.json").write_text("{bad")
    with pytest.raises(InputError, match=r"run.json:1: invalid JSON"):
        read_run(tmp_path / "r")
    with pytest.raises(InputError, match="run folder not found"):
        read_run(tmp_path / "nope")


def test_existing_folder_needs_force_and_is_swapped_whole(tmp_path):
    d = tmp_path / "run"
    write_run_folder(d, poses(3), views(4), {"n": 1})
    (d / "stale.txt").write_text("from an older run")
    with pytest.raises(S2PError, match="exists and is not empty"):
        write_run_folder(d, poses(2), None, {"n": 2})
    assert json.loads((d / "run.json").read_text()) == {"n": 1}
    write_run_folder(d, poses(2), None, {"n": 2}, force=True)
    # the new folder replaced the old one as a whole: no file of the old run is left
    assert sorted(p.name for p in d.iterdir()) == ["poses.csv", "run.json"]
    assert json.loads((d / "run.json").read_text()) == {"n": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no temporary or lock left


def test_interrupted_write_keeps_the_old_run(tmp_path, monkeypatch):
    import seg2pose.io.run as R

    d = tmp_path / "run"
    write_run_folder(d, poses(3), views(4), {"n": 1})
    before = {p.name: p.read_bytes() for p in d.iterdir()}

    def boom(table, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(R, "format_views", boom)
    with pytest.raises(KeyboardInterrupt):
        write_run_folder(d, poses(1), views(2), {"n": 2}, force=True)
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_second_writer_is_refused(tmp_path):
    d = tmp_path / "run"
    with run_lock(d) as lock:
        holder = json.loads(lock.read_text())
        assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
        with pytest.raises(S2PError, match=rf"being written by process {os.getpid()}"):
            write_run_folder(d, poses(), views(), {})
    assert not d.exists() and not lock.exists()


def test_stale_lock_of_a_dead_process_is_taken_over(tmp_path, capsys):
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # a pid that no longer runs
    d = tmp_path / "run"
    lock = tmp_path / ".run.lock"
    lock.write_text(json.dumps({"pid": p.pid, "host": socket.gethostname(), "time": "then"}))
    write_run_folder(d, poses(), views(), {"n": 1})
    err = capsys.readouterr().err
    assert f"note: taking over the lock {lock} of process {p.pid}" in err
    assert json.loads((d / "run.json").read_text()) == {"n": 1} and not lock.exists()


def test_relative_path(tmp_path):
    assert relative_path(tmp_path / "scene", tmp_path / "scene" / "out" / "run") == "../.."
    assert relative_path(tmp_path / "m" / "a.safetensors", tmp_path / "r") == "../m/a.safetensors"
