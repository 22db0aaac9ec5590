"""Fuzzing of ``s2p import-mcap`` (hypothesis): valid exports restore exactly; near-valid and
random files end in the project's one-line error, with nothing written outside the output
folder, or restore a scene that every reader accepts (``load_scene`` as ``s2p info`` does, the
run folder's run.json, poses.csv and views.csv)."""

from __future__ import annotations

import contextlib
import io
import json

from fuzz_fixtures import FUZZ, finite, folder, mutate_json, only_s2p_errors
from hostile_fixtures import write_s2p_mcap
from hypothesis import given
from hypothesis import strategies as st

from seg2pose.io.poses import read_poses

ROW = {"frame": 0, "track_id": 1, "class": "car", "x": 1.5, "y": -2.25, "z": 0.0,
       "heading": 0.5, "l": 4.0, "w": 2.0, "h": 1.5}


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), finite, finite), min_size=1, max_size=8,
                unique_by=lambda r: r[0]))
def test_mcap_import_round_trip(rows):
    from s2p_review.mcap_import import import_mcap

    msgs = [{"frame": f, "rows": [dict(ROW, frame=f, x=x, y=y)]} for f, x, y in sorted(rows)]
    with folder() as d:
        f = write_s2p_mcap(d / "x.mcap", {"version": 1}, "ground_points.csv", msgs)
        run = import_mcap(f, d / "out")
        t = read_poses(run / "poses.csv")
        restored_is_readable(run)
        assert t.frame.tolist() == sorted(r[0] for r in rows)
        assert t.xyz[:, :2].tolist() == [[x, y] for _, x, y in sorted(rows)]


@FUZZ
@given(st.data())
def test_mcap_import_near_valid(data):
    from s2p_review.mcap_import import import_mcap

    msgs = [{"frame": f, "rows": [dict(ROW, frame=f, track_id=t) for t in (1, 2)]} for f in range(3)]
    scene_d = {"version": 1, "ground_points": "ground_points.csv"}
    which = data.draw(st.sampled_from(["poses", "scene", "bytes"]))
    with folder() as d:
        if which == "poses":
            i = data.draw(st.integers(0, len(msgs) - 1))
            msgs[i] = mutate_json(data, msgs[i])  # the text of one message, maybe not JSON
        elif which == "scene":
            with contextlib.suppress(ValueError):
                scene_d = json.loads(mutate_json(data, scene_d))
        gname = scene_d.get("ground_points") if isinstance(scene_d, dict) else None
        f = write_s2p_mcap(d / "x.mcap", scene_d, gname if isinstance(gname, str) and gname else "g.csv", msgs)
        if which == "bytes":
            raw = f.read_bytes()
            f.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1))])
        run = only_s2p_errors(lambda: import_mcap(f, d / "out" / "scene"))
        # nothing is ever written outside the output folder
        assert sorted(p.name for p in d.iterdir()) in (["x.mcap"], ["out", "x.mcap"])
        if run is not None:  # what it restored, every reader accepts
            restored_is_readable(run)


def restored_is_readable(run) -> None:
    """The restored scene as ``s2p info`` reads it, and its run folder (run.json, poses.csv,
    views.csv) as review, eval and export read it."""
    from seg2pose.cli.scene import info
    from seg2pose.io.run import read_run
    from seg2pose.io.scene import load_scene

    scene = load_scene(run.parent.parent)
    with contextlib.redirect_stdout(io.StringIO()):
        info(scene.root)
    read_run(run, known_classes=None)


@FUZZ
@given(st.binary(max_size=400))
def test_mcap_import_random_bytes(blob):
    from s2p_review.mcap_import import import_mcap

    with folder() as d:
        (d / "x.mcap").write_bytes(blob)
        only_s2p_errors(lambda: import_mcap(d / "x.mcap", d / "out"))
