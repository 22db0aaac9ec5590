"""T-Analyst CSV into and out of an annotation project: keyframes from detections, headings
from motion, ids and types kept, errors naming the CSV line."""

import math

import numpy as np
import pytest
from review_fixtures import make_scene

from annotate import Project
from annotate.tanalyst_io import annotations_to_tanalyst, import_tanalyst
from seg2pose.core.errors import InputError
from seg2pose.io.tanalyst import format_tanalyst, parse_tanalyst, read_tanalyst

HEADER = "Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp"
# 10 fps scene, frame 0 at 12:00:00.000: road user 3 (car) at frames 0, 5, 10, user 7 at 2, 6
CSV = "\n".join([HEADER,
                 "1;Car;3;-8;-1,5;12:00:00.000",
                 "2;Car;3;-5;-1,5;12:00:00.500",
                 "3;Car;3;-2;-1,5;12:00:01.000",
                 "4;Pedestrian;7;1;2;12:00:00.200",
                 "5;Pedestrian;7;1;4;12:00:00.600"]) + "\n"
START = 12 * 3600_000


@pytest.fixture
def project(tmp_path):
    p = Project.open(make_scene(tmp_path / "scene", n_frames=30))
    yield p
    p.close()


def test_import_makes_keyframes_and_export_writes_the_file_back(project):
    ch = import_tanalyst(project, parse_tanalyst(CSV), start_ms=START)
    assert ch.created == {3, 7} and project.seq == 1  # one journalled, undoable step
    car, ped = project.track(3), project.track(7)
    assert (car.cls, ped.cls) == ("car", "pedestrian") and car.frames == [0, 5, 10]
    assert ped.frames == [2, 6] and ped.keyframes[2].flags == ("imported",)
    assert car.keyframes[5][:3] == (-5.0, -1.5, 0.0)
    assert ped.keyframes[6].heading == pytest.approx(math.pi / 2)
    assert car.meta["tanalyst"] == {"road_user_id": 3, "type": "Car"}
    out = annotations_to_tanalyst(project, start_ms=START, keyframes_only=True)
    assert format_tanalyst(out) == CSV
    full = annotations_to_tanalyst(project, start_ms=START)
    assert len(full) == 11 + 5 and full.time_ms[:3].tolist() == [START, START + 100, START + 200]
    np.testing.assert_allclose(full.xy[:11, 0], -8 + 0.6 * np.arange(11), atol=1e-9)
    project.undo()
    assert not project.tracks


def test_import_twice_is_refused_unless_replacing(project, tmp_path):
    import_tanalyst(project, parse_tanalyst(CSV), start_ms=START)
    with pytest.raises(InputError, match="road user 3 was imported before \\(track 3\\)"):
        import_tanalyst(project, parse_tanalyst(CSV), start_ms=START)
    ch = import_tanalyst(project, parse_tanalyst(CSV.replace("-8;-1,5", "-7;-1,5")),
                         start_ms=START, replace=True)
    assert sorted(project.tracks) == [3, 7] and project.track(3).keyframes[0].x == -7.0
    assert ch.deleted == frozenset() and ch.tracks == {3, 7}


def test_ids_taken_by_other_tracks_get_new_ones(project):
    project.create_track("bicyclist", track_id=3)
    ch = import_tanalyst(project, parse_tanalyst(CSV), start_ms=START)
    assert ch.created == {4, 7} and project.track(4).meta["tanalyst"]["road_user_id"] == 3
    out = annotations_to_tanalyst(project, start_ms=START, keyframes_only=True)
    assert out.road_user_id.tolist() == [3, 3, 3, 7, 7]


@pytest.mark.parametrize("edit, line, message", [
    (lambda s: s.replace("Pedestrian;7", "Tram;7"), 5, "road user type 'Tram' is not a class"),
    (lambda s: s.replace("12:00:01.000", "12:00:03.000"), 4, "frame 30 is outside the scene's frames 0..29"),
    (lambda s: s.replace("12:00:00.500", "12:00:00.540"), 3, "0.40 frames from the nearest frame"),
    (lambda s: s.replace("-5;-1,5", "-500;-1,5"), 3, "refused"),
    (lambda s: s.replace("12:00:00.200", "11:59:59.000"), 5, "before the video's start"),
])
def test_import_errors_name_the_line(project, tmp_path, edit, line, message):
    p = tmp_path / "t.csv"
    p.write_text(edit(CSV))
    with pytest.raises(InputError, match=message) as e:
        import_tanalyst(project, read_tanalyst(p), start_ms=START, file=p)
    assert str(e.value).startswith(f"{p}:{line}:")
    assert not project.tracks and project.seq == 0  # nothing half-imported


def test_type_map_and_two_detections_in_one_frame(project, tmp_path):
    t = parse_tanalyst(CSV.replace("Pedestrian;7", "Tram;7"))
    import_tanalyst(project, t, start_ms=START, type_map={"Tram": "bicyclist"})
    assert project.track(7).cls == "bicyclist"
    out = annotations_to_tanalyst(project, start_ms=START, keyframes_only=True)
    assert list(out.road_user_type) == ["Car"] * 3 + ["Tram"] * 2  # the file's own type back
    p = tmp_path / "d.csv"
    p.write_text(CSV.replace("12:00:00.500", "12:00:00.001"))  # 0.01 frames from frame 0
    with pytest.raises(InputError, match="two detections in frame 0") as e:
        import_tanalyst(project, read_tanalyst(p), start_ms=START, file=p, replace=True)
    assert e.value.line == 3
