"""`s2p review` through the command layer: outputs, errors as one line, frame ranges."""

from __future__ import annotations

import pytest
from review_fixtures import make_run, review_scene, rrd_rows
from typer.testing import CliRunner
from video_fixtures import single_threaded_opencv

from seg2pose.cli.common import parse_frames
from seg2pose.core.errors import InputError

_opencv_one_thread = pytest.fixture(scope="module", autouse=True)(single_threaded_opencv)
tiny = pytest.fixture(scope="module")(review_scene)



def test_parse_frames():
    assert parse_frames("3:9") == (3, 9)
    assert parse_frames(None) is None
    for bad in ("3", "9:3", "a:b", "-1:2"):
        with pytest.raises(InputError, match="--frames"):
            parse_frames(bad)


# --- CLI -------------------------------------------------------------------------------------------
def test_cli_review_and_errors(tiny):
    from seg2pose.cli import app

    scene, base, s2pn, root = tiny
    runner = CliRunner()
    out = root / "cli.rrd"
    r = runner.invoke(app, ["review", str(scene.root), "--run", str(base), "--run", str(s2pn),
                            "-o", str(out), "--frames", "2:7", "--no-video"])
    assert r.exit_code == 0, r.output
    assert "rerun " + str(out) in r.output
    rows, _, _ = rrd_rows(out)
    assert rows["/world/road_users/run-s2pn/12"] == 6
    r = runner.invoke(app, ["review", str(scene.root), "--run", str(base), "-o", str(out)])
    assert r.exit_code != 0 and "--force" in str(r.exception)


def test_cli_main_prints_one_line_error(tiny, monkeypatch, capsys):
    import sys

    from seg2pose import cli

    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad3", cameras=["zz"])
    monkeypatch.setattr(sys, "argv", ["s2p", "review", str(scene.root), "--run", str(bad),
                                      "-o", str(root / "x.rrd")])
    with pytest.raises(SystemExit) as e:
        cli.main()
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "run.json" in err and "zz" in err and len(err.strip().splitlines()) == 1
