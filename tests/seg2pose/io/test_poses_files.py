"""poses.csv: exact round trips and bad input naming the line."""


import numpy as np
import pytest
from io_fixtures import write

from seg2pose.core.errors import InputError
from seg2pose.io.poses import PoseTable, read_poses, write_poses


def test_poses_round_trip_exact(tmp_path):
    rng = np.random.default_rng(1)
    n = 20
    t = PoseTable(np.sort(rng.integers(0, 9, n)), rng.permutation(n),
                  np.array(["car", "pedestrian"] * 10, object), rng.normal(size=(n, 3)) * 1e3,
                  np.r_[rng.uniform(-3, 3, n - 1), np.nan], rng.uniform(0.1, 5, (n, 3)))
    write_poses(tmp_path / "p.csv", t)
    r = read_poses(tmp_path / "p.csv")
    assert np.array_equal(r.frame, t.frame) and np.array_equal(r.track_id, t.track_id)
    assert list(r.cls) == list(t.cls)
    assert np.array_equal(r.xyz, t.xyz) and np.array_equal(r.size, t.size)
    assert np.array_equal(r.heading, t.heading, equal_nan=True)


def test_poses_bad_input(tmp_path):
    head = "frame,track_id,class,x,y,z,heading\n"
    with pytest.raises(InputError, match=r"p.csv:1: expected header"):
        read_poses(write(tmp_path, "p.csv", "frame,id\n"))
    with pytest.raises(InputError, match=r"p.csv:3: frame 0 comes after frame 2"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,car,0,0,0,0\n0,1,car,0,0,0,0\n"))
    with pytest.raises(InputError, match=r"p.csv:2: field 'class': unknown class 'tram'"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,tram,0,0,0,0\n"), known_classes={"car"})
    with pytest.raises(InputError, match=r"p.csv:2: x, y, z must be finite"):
        read_poses(write(tmp_path, "p.csv", head + "2,1,car,inf,0,0,0\n"))
