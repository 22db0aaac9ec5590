"""Calibration files (io/calib_files.py): world files, two reference points, pairs and survey
CSVs, with hand-derived answers and one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.io.calib_files import (
    aerial_to_world,
    read_pairs,
    read_survey,
    read_world_file,
    two_point_georeference,
    world_to_aerial,
    write_world_file,
)


def test_world_file_read_right(tmp_path):
    """5 cm pixels, north up, the centre of the top-left pixel at (100.025, 199.975): the
    top-left corner of the image is (100, 200); pixel corner (u, v) = (200, 100) lies 10 m east
    and 5 m south of it."""
    p = tmp_path / "aerial.pgw"
    p.write_text("0.05\n0\n0\n-0.05\n100.025\n199.975\n")
    A = read_world_file(p)
    np.testing.assert_allclose(aerial_to_world(A, [[0, 0], [0.5, 0.5], [200, 100]]),
                               [[100, 200], [100.025, 199.975], [110, 195]], atol=1e-9)
    np.testing.assert_allclose(world_to_aerial(A, [[110, 195]]), [[200, 100]], atol=1e-9)
    write_world_file(tmp_path / "again.pgw", A)
    np.testing.assert_allclose(read_world_file(tmp_path / "again.pgw"), A, atol=1e-12)


def test_rotated_world_file(tmp_path):
    """A = s cos, D = s sin (the image's x axis turned 30 degrees anticlockwise), B = s sin,
    E = -s cos: pixel corner (10, 0) lies 10 s along the turned axis from the corner."""
    s, th = 0.1, np.radians(30)
    a, d, b, e = s * np.cos(th), s * np.sin(th), s * np.sin(th), -s * np.cos(th)
    c, f = 5.0 + 0.5 * (a + b), 7.0 + 0.5 * (d + e)  # the top-left corner at (5, 7)
    p = tmp_path / "r.jgw"
    p.write_text("\n".join(repr(float(v)) for v in (a, d, b, e, c, f)))
    A = read_world_file(p)
    np.testing.assert_allclose(aerial_to_world(A, [[0, 0], [10, 0]]),
                               [[5, 7], [5 + np.cos(th), 7 + np.sin(th)]], atol=1e-12)


@pytest.mark.parametrize("text,msg", [
    ("0.05\n0\n0\n-0.05\n100\n", "six numbers"),
    ("0.05\n0\n0\nabc\n100\n200\n", "six numbers"),
    ("0\n0\n0\n0\n100\n200\n", "not a usable world file"),
    ("\x89PNG\r\n\x1a\n", "six numbers"),
])
def test_not_a_world_file(tmp_path, text, msg):
    p = tmp_path / "bad.pgw"
    p.write_text(text)
    with pytest.raises(InputError, match=msg) as e:
        read_world_file(p)
    assert "bad.pgw" in str(e.value) and "\n" not in str(e.value)


def test_two_reference_points():
    """Two pixels 100 px apart along the image's x axis, 5 m apart along world +y: 5 cm per
    pixel with the image's x axis pointing north, so its y axis (down) points east: the pixel
    100 px below the first lies 5 m east of it."""
    A = two_point_georeference([[0, 0], [100, 0]], [[10, 20], [10, 25]])
    np.testing.assert_allclose(aerial_to_world(A, [[0, 0], [100, 0], [0, 100]]),
                               [[10, 20], [10, 25], [15, 20]], atol=1e-12)
    with pytest.raises(InputError, match="less than a pixel apart"):
        two_point_georeference([[3, 3], [3.2, 3]], [[0, 0], [1, 1]])


def test_pairs_csv(tmp_path):
    p = tmp_path / "pairs.csv"
    p.write_text("camera,u,v,x,y,z,name\nc0,10,20,1,2,,kerb\nc0,30,40,3,4,0.5,\nc1,1,2,3,4,5,a\n")
    pairs = read_pairs(p)
    assert sorted(pairs) == ["c0", "c1"]
    np.testing.assert_allclose(pairs["c0"]["uv"], [[10, 20], [30, 40]])
    assert np.isnan(pairs["c0"]["X"][0, 2]) and pairs["c0"]["X"][1, 2] == 0.5
    assert pairs["c0"]["names"] == ["kerb", "line 3"]
    p.write_text("c0,10,20,1,2,0\nc0,10,x,1,2,0\n")
    with pytest.raises(InputError, match=r"pairs.csv:2: field 'v': expected a number"):
        read_pairs(p)
    p.write_text("c0,10,20,1,2\n")
    with pytest.raises(InputError, match="pairs.csv:1: expected fields camera,u,v,x,y,z"):
        read_pairs(p)


def test_survey_csv(tmp_path):
    p = tmp_path / "survey.csv"
    p.write_text("name,x,y,z\nA,1,2,3\nB,4,5,\n")
    names, P = read_survey(p)
    assert names == ["A", "B"] and P[0].tolist() == [1, 2, 3] and np.isnan(P[1, 2])
    p.write_text("A,1,2,3\nA,4,5,6\n")
    with pytest.raises(InputError, match="survey.csv:2: duplicate point name 'A'"):
        read_survey(p)
