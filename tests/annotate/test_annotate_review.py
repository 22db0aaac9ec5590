"""Review aids: suggested keyframes, keyframe density, gaps and implausible motion."""

import math

import pytest
from review_fixtures import EST_OFFSET, make_run, make_scene

from annotate import Project
from annotate.review import keyframe_density, plausibility_report, suggest_keyframes
from seg2pose.io.poses import read_poses


@pytest.fixture
def scene(tmp_path):
    return make_scene(tmp_path / "scene", n_frames=30)


def test_suggestions_rank_the_largest_disagreement_with_the_run(scene, tmp_path):
    gt = read_poses(scene.gt_path)
    car = gt.take(gt.track_id == 12)
    with Project.open(scene, run=make_run(scene, tmp_path / "run")) as p:
        p.create_track("car", meta={"run_track": 12})
        p.set_keyframe(1, 0, *car.xyz[0, :2], heading=0.0)
        p.set_keyframe(1, 29, car.xyz[29, 0], car.xyz[29, 1] + 2.0, heading=0.0)
        p.set_interpolation(1, "linear")
        sug = suggest_keyframes(p, threshold=1.0, min_gap=10)
        # interpolation at frame 28: truth + (0, 2 * 28 / 29); the run: truth + (0.3, -0.4)
        expect = math.hypot(-EST_OFFSET[0], 2 * 28 / 29 - EST_OFFSET[1])
        assert sug[0].track == 1 and sug[0].frame == 28
        assert sug[0].distance == pytest.approx(expect, abs=1e-9)
        assert sug[0].reference == pytest.approx(tuple(car.xyz[28, :2] + EST_OFFSET[:2]))
        assert [s.frame for s in sug] == [28, 18]  # one per 10 frames, above 1 m only
        assert all(s.distance > 1.0 for s in sug)
        # without the run link, the nearest run track in most frames is found
        p.create_track("car")
        p.set_keyframe(2, 0, *car.xyz[0, :2], heading=0.0)
        p.set_keyframe(2, 29, car.xyz[29, 0], car.xyz[29, 1] + 2.0, heading=0.0)
        p.set_interpolation(2, "linear")
        assert [s.frame for s in suggest_keyframes(p, threshold=1.0, tracks=[2])] == [28, 18]
        # the masks' normal positions as reference: near the truth, so fewer, smaller hits
        normal = suggest_keyframes(p, source="normal", threshold=1.0, tracks=[1])
        assert all(s.source == "normal" and s.track == 1 for s in normal)


def test_keyframe_density(scene):
    with Project.open(scene) as p:
        p.create_track("pedestrian")
        for f in (0, 5, 25):
            p.set_keyframe(1, f, 0.0, float(f) * 0.1, heading=0.0, flags=["estimate"] if f else [])
        d = keyframe_density(p)[0]
        assert d["keyframes"] == 3 and d["frames"] == 26 and d["longest_gap"] == 20
        assert d["per_100_frames"] == pytest.approx(300 / 26)
        assert d["unchecked"] == pytest.approx(2 / 3)


def test_report_gaps_and_implausible_speeds(scene):
    with Project.open(scene) as p:
        p.create_track("pedestrian")
        for f, x in ((0, 0.0), (5, 1.0), (20, 4.0)):
            p.set_keyframe(1, f, x, 0.0, heading=0.0)
        p.mark(1, 8, 12, "outside")
        p.create_track("car")
        p.set_keyframe(2, 0, -10.0, 0.0, heading=0.0)
        p.set_keyframe(2, 10, 10.0, 0.0, heading=0.0)   # 20 m in 1 s: 20 m/s, plausible
        p.set_keyframe(2, 12, 18.0, 0.0, heading=0.0)   # 8 m in 0.2 s: 40 m/s
        issues = plausibility_report(p)
        gaps = [(i.first, i.last) for i in issues if i.kind == "gap"]
        assert gaps == [(6, 7), (13, 19)]
        speed = [i for i in issues if i.kind == "speed"]
        assert len(speed) == 1 and speed[0].track == 2 and speed[0].value > 30
        assert "m/s" in speed[0].message and speed[0].first >= 10
        assert any(i.kind == "acceleration" and i.track == 2 for i in issues)
        assert not [i for i in issues if i.track == 1 and i.kind != "gap"]
        # limits are per class and overridable
        assert not [i for i in plausibility_report(p, {"car": (100.0, 1e9)}) if i.track == 2]
