"""gt/poses.csv's optional ``source`` column (annotated ground truth): exact round trips, old
files stay valid, unknown sources name the line."""

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.io.poses import PoseTable, format_poses, read_poses, write_poses


def table(with_size: bool, with_source: bool) -> PoseTable:
    return PoseTable([0, 0, 1], [1, 2, 1], ["car", "pedestrian", "car"],
                     [[1.5, -2.25, 0.1], [0.1, 0.2, 0.3], [1.75, -2.25, 0.1]], [0.5, np.nan, 0.25],
                     [[4.5, 1.8, 1.5], [0.6, 0.6, 1.75], [4.5, 1.8, 1.5]] if with_size else None,
                     ["keyframe", "occluded", "interpolated"] if with_source else None)


@pytest.mark.parametrize("with_size", [False, True])
def test_source_round_trip(tmp_path, with_size):
    t = table(with_size, True)
    write_poses(tmp_path / "p.csv", t)
    text = (tmp_path / "p.csv").read_text()
    assert text.splitlines()[0].endswith(",heading" + (",l,w,h" if with_size else "") + ",source")
    assert text.splitlines()[1].endswith(",keyframe")
    back = read_poses(tmp_path / "p.csv")
    assert back.source.tolist() == ["keyframe", "occluded", "interpolated"]
    assert np.array_equal(back.xyz, t.xyz) and format_poses(back) == text
    assert back.take([2]).source.tolist() == ["interpolated"]
    assert PoseTable.concat([back, back]).source.tolist() == t.source.tolist() * 2
    # mixing annotated and plain tables drops the column rather than inventing sources
    assert PoseTable.concat([back, table(with_size, False)]).source is None


def test_files_without_source_stay_valid(tmp_path):
    write_poses(tmp_path / "p.csv", table(True, False))
    assert "source" not in (tmp_path / "p.csv").read_text()
    assert read_poses(tmp_path / "p.csv").source is None


def test_bad_source_names_the_line(tmp_path):
    p = tmp_path / "p.csv"
    write_poses(p, table(False, True))
    p.write_text(p.read_text().replace("occluded", "hidden"))
    with pytest.raises(InputError, match="unknown source 'hidden'") as e:
        read_poses(p)
    assert str(e.value).startswith(f"{p}:3:")
    p.write_text(p.read_text().replace(",hidden", ""))
    with pytest.raises(InputError, match="expected 8 fields, got 7") as e:
        read_poses(p)
    assert e.value.line == 3
