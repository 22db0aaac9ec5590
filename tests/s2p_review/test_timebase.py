"""Real times: the scene's optional start time (validated), frames <-> times, and the two
timelines of a Rerun recording (``frame`` and the wall-clock ``time``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from review_fixtures import make_run, make_scene

from s2p_review.timebase import Timebase, scene_timebase
from seg2pose.core.errors import InputError
from seg2pose.io.scene import load_scene, parse_start_time

START_NS = 1623657600 * 10**9  # 2021-06-14T08:00:00Z


def test_parse_start_time_known_answers():
    assert parse_start_time("2021-06-14T08:00:00Z") == START_NS
    assert parse_start_time("2021-06-14T10:00:00.25+02:00") == START_NS + 250_000_000
    assert parse_start_time("1970-01-01T00:00:00.000001Z") == 1000
    for bad in ("2021-06-14T08:00:00", "yesterday", 12, None):
        with pytest.raises(InputError, match="ISO 8601"):
            parse_start_time(bad, field="start_time")


def test_scene_start_time_round_trip_and_validation(tmp_path):
    scene = make_scene(tmp_path / "s", n_frames=2)
    assert scene.start_time is None and scene.start_time_ns is None
    d = json.loads((scene.root / "scene.json").read_text())
    d["start_time"] = "2021-06-14T08:00:00Z"
    (scene.root / "scene.json").write_text(json.dumps(d))
    s2 = load_scene(scene.root)
    assert s2.start_time_ns == START_NS
    s2.save()
    assert json.loads((scene.root / "scene.json").read_text())["start_time"] == "2021-06-14T08:00:00Z"
    d["start_time"] = "2021-06-14 08:00"
    (scene.root / "scene.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"scene.json.*start_time.*ISO 8601"):
        load_scene(scene.root)


def test_timebase_frames_and_times():
    tb = Timebase(fps=13.333, start_ns=START_NS)
    f = np.array([0, 1, 520, 679, 21299])
    ns = tb.ns(f)
    np.testing.assert_array_equal(ns - START_NS, np.rint(f * 1e9 / 13.333).astype(np.int64))
    np.testing.assert_array_equal(tb.frame_of(ns), f)
    assert Timebase(10.0).ns1(7) == 700_000_000


def test_rrd_has_frame_and_real_time_timelines(tmp_path):
    import rerun.chunk as rc

    from s2p_review.recording import LogStyle
    from s2p_review.session import RecordOptions, record

    scene = make_scene(tmp_path / "s", n_frames=5)
    run = make_run(scene, tmp_path / "s" / "out" / "r")
    res = record(scene, [run], tmp_path / "r.rrd",
                 RecordOptions(start_ns=START_NS, style=LogStyle(masks=False)))
    assert scene_timebase(scene, START_NS).start_ns == START_NS
    for ch in rc.RrdReader(res.rrd).stream():
        if ch.entity_path == "/world/road_users/r/12" and not ch.is_static:
            b = ch.to_record_batch()
            frames = b.column("frame").to_pylist()
            times = b.column("time").cast("int64").to_pylist()
            assert str(b.schema.field("time").type).startswith("timestamp")
            break
    assert frames == [0, 1, 2, 3, 4]
    assert times == [START_NS + f * 100_000_000 for f in frames]  # 10 fps
