"""``s2p conflicts`` writes its conflicts CSV, PET-only CSV, conflict map (--map) and TCT chart
(--tct-chart) as one set (``seg2pose.io.atomic.outputs``): a refusal leaves all four old, and a
kill at any step of the set's commit leaves each whole and, once the next writer of any one
of them has finished the set (``finish_commits``), all four new. The pictures were written
after the CSVs' set, each on its own: a kill or a refusal between them left a new map beside
an old CSV, or new CSVs beside an old chart."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

from seg2pose.core.errors import S2PError

NAMES = ("c.csv", "pet.csv", "map.png", "tct.png")


def _write_crossing(path: Path, x2: float) -> None:
    """Car 1 along +x through the origin at 3 s, car 2 along +y at x = ``x2`` through y = 0 at
    5 s, 10 m/s, 30 fps (x2 = 0: PET 1.42 s; 0.5: 1.37 s, car 1's rear leaves the shared
    square 0.5 m later): a PET-only encounter, drawn on the map where car 2 entered."""
    from seg2pose.io.poses import PoseTable, write_poses

    t = np.arange(0, 8, 1 / 30)
    f, n, z = np.arange(len(t)), len(t), np.zeros(len(t))
    write_poses(path, PoseTable(np.r_[f, f], np.r_[np.ones(n), 2 * np.ones(n)], np.array(["car"] * 2 * n, object),
                                np.c_[np.r_[10 * (t - 3), z + x2], np.r_[z, 10 * (t - 5)], np.zeros(2 * n)],
                                np.r_[z, np.full(n, np.pi / 2)], np.tile([4.0, 1.8, 1.5], (2 * n, 1))).sorted())


def _argv(poses: Path, root: Path, *extra: str) -> list[str]:
    """The CSVs in ``root``/csv, the pictures in ``root``/pics (the set spans two folders)."""
    c, p, m, t = _paths(root)
    return ["conflicts", str(poses), "-o", str(c), "--pet-only", str(p), "--map", str(m), "--tct-chart", str(t),
            "--fps", "30", "--all-pairs", *extra]


def _paths(root: Path) -> list[Path]:
    return [root / "csv" / NAMES[0], root / "csv" / NAMES[1], root / "pics" / NAMES[2], root / "pics" / NAMES[3]]


def _run(argv: list[str]) -> int:
    from seg2pose.cli import main

    try:
        main(argv)
    except SystemExit as e:
        return int(e.code or 0)
    return 0


def _state(root: Path) -> list[bytes | None]:
    return [p.read_bytes() if p.exists() else None for p in _paths(root)]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """(folder, old poses, new poses, the old set's bytes, the new set's bytes): the new run
    another crossing and another TCT boundary (--tct-decel 5), so all four outputs differ."""
    d = tmp_path_factory.mktemp("conflicts-set")
    old_p, new_p = d / "old.csv", d / "new.csv"
    _write_crossing(old_p, 0.0)
    _write_crossing(new_p, 0.5)
    assert _run(_argv(old_p, d / "old")) == 0
    assert _run(_argv(new_p, d / "new", "--tct-decel", "5")) == 0
    old, new = _state(d / "old"), _state(d / "new")
    assert all(a is not None and a != b for a, b in zip(old, new))
    return d, old_p, new_p, old, new


def _put_old(root: Path, old: list[bytes | None]) -> None:
    for p, data in zip(_paths(root), old):
        p.parent.mkdir(parents=True, exist_ok=True)
        assert data is not None
        p.write_bytes(data)


def _hidden(root: Path) -> list[str]:
    """What lies beside the outputs but their locks (partial builds, commit records, old
    outputs set aside)."""
    return sorted(e.name for d in (root / "csv", root / "pics") for e in d.iterdir()
                  if e.name not in NAMES and not e.name.endswith(".lock"))


def test_a_refused_picture_leaves_the_whole_set_old(runs, tmp_path, monkeypatch, capsys):
    """The TCT chart fails (the last output): the CSVs and the map stay old as well."""
    import seg2pose.safety.conflict_map as CM

    _, _, new_p, old, _ = runs
    _put_old(tmp_path, old)

    def refuse(*a, **k):
        raise S2PError("refused midway")
    monkeypatch.setattr(CM, "tct_chart_png", refuse)
    assert _run(_argv(new_p, tmp_path, "--tct-decel", "5", "--force")) != 0
    assert "refused midway" in capsys.readouterr().err
    assert _state(tmp_path) == old
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("step", ["recorded:1", "set-swap:1", "set-swap:2", "set-swap:3"])
def test_a_set_killed_at_its_commit_is_finished_whole_by_the_next_writer(runs, tmp_path, step):
    """SIGKILL (S2P_KILL_AT, in a forked child) once the set's records are durable, and after
    its 1st, 2nd and 3rd of 4 swaps: each output is whole (old or new bytes); the next writer
    of the TCT chart alone (``finish_commits``, which every writer of an output runs first)
    makes all four the new set's and leaves nothing beside them."""
    from seg2pose.io.atomic import finish_commits

    _, _, new_p, old, new = runs
    _put_old(tmp_path, old)
    pid = os.fork()
    if pid == 0:  # the child: the command, killed at the step
        code = 3
        try:
            os.environ["S2P_KILL_AT"] = step
            code = _run(_argv(new_p, tmp_path, "--tct-decel", "5", "--force"))
        finally:
            os._exit(code)
    status = os.waitpid(pid, 0)[1]
    assert os.waitstatus_to_exitcode(status) == -signal.SIGKILL
    state = _state(tmp_path)
    assert all(s in (a, b) for s, a, b in zip(state, old, new)), [s in (a, b) for s, a, b in zip(state, old, new)]
    assert state != new if step != "set-swap:3" else True  # killed before its last swap
    finish_commits(_paths(tmp_path)[3])
    assert _state(tmp_path) == new
    assert _hidden(tmp_path) == []
