"""Conflicts in review: `s2p review --conflicts` logs events, plots and highlights; `s2p export
--conflicts` carries the conflicts as events on /s2p/conflicts."""

from __future__ import annotations

from collections import Counter

import pytest
from review_fixtures import make_run, make_scene

from s2p_review.conflicts import TOPIC, read_conflicts
from s2p_review.recording import LogStyle
from s2p_review.session import RecordOptions, record
from seg2pose.core.errors import InputError

N_FRAMES = 60


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny scene (a car, a pedestrian, a bicyclist), its run and every encounter of it."""
    from seg2pose.cli import main

    root = tmp_path_factory.mktemp("conf")
    scene = make_scene(root / "scene", n_frames=N_FRAMES)
    run = make_run(scene, root / "run")
    csv_path = root / "conflicts.csv"
    with pytest.raises(SystemExit) as e:
        main(["conflicts", str(run), "-o", str(csv_path), "--all-pairs", "--horizon", "10"])
    assert e.value.code == 0
    return scene, run, csv_path, root


def test_rrd_holds_conflicts(tiny):
    import rerun.chunk as rc

    scene, run, csv_path, root = tiny
    conflicts = read_conflicts(csv_path)
    assert len(conflicts) == 3  # three road users: three pairs within 100 m
    out = record(scene, [run], root / "c.rrd", RecordOptions(
        style=LogStyle(masks=False, video=False), conflicts=csv_path)).rrd
    rows = Counter()
    for ch in rc.RrdReader(out).stream():
        if not ch.is_static:
            rows[ch.entity_path] += ch.num_rows
    assert rows["/conflicts/events"] == 3
    assert all(rows[f"/conflicts/distance/c{k}"] > 0 for k in range(3))


def test_mcap_carries_conflicts_as_events(tiny):
    import json

    from mcap.reader import make_reader

    from s2p_review.mcap_export import ExportOptions, export_mcap

    scene, run, csv_path, root = tiny
    out = export_mcap(scene, run, root / "c.mcap", ExportOptions(
        video=False, conflicts=csv_path, layout=False)).path
    with open(out, "rb") as f:
        msgs = [(ch, json.loads(m.data)) for _, ch, m in make_reader(f).iter_messages(topics=[TOPIC])]
    assert len(msgs) == 3
    ch, first = msgs[0]
    assert ch.message_encoding == "json"
    assert {"track_a", "track_b", "type", "min_ttc_s", "pet_s", "frame"} <= set(first)


def test_bad_conflicts_file_names_line(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("track_a,track_b\n1,2\n")
    with pytest.raises(InputError, match="missing columns"):
        read_conflicts(p)
    (tiny_header := tmp_path / "d.csv").write_text(
        "track_a,class_a,track_b,class_b,type,conflict,first_frame,last_frame,min_ttc_s,"
        "min_ttc_frame,pet_s,pet_first_track,pet_exit_frame,pet_enter_frame\n"
        "1,car,2,car,crossing,1,0,10,abc,,,,,\n")
    with pytest.raises(InputError, match=r"d.csv:2: field 'min_ttc_s'"):
        read_conflicts(tiny_header)


def test_conflicts_review_option(tiny, capsys):
    """`s2p conflicts RUN -o c.csv --review r.rrd`: both written; a file instead of a run folder
    is one line."""
    from seg2pose.cli import main

    scene, run, _, root = tiny
    for argv, code in (([str(run), "-o", str(root / "c2.csv"), "--review", str(root / "r.rrd"),
                         "--all-pairs", "--horizon", "10"], 0),
                       ([str(run / "poses.csv"), "-o", str(root / "c3.csv"), "--review",
                         str(root / "r3.rrd")], 2)):
        with pytest.raises(SystemExit) as e:
            main(["conflicts", *argv])
        assert e.value.code == code
    assert (root / "r.rrd").stat().st_size > 0 and (root / "c2.csv").exists()
    assert "--review needs a run folder" in capsys.readouterr().err
