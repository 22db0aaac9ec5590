"""The pose reader of `s2p conflicts` for long recordings (seg2pose.safety.tracks.
read_poses_fast): the same table as seg2pose.io.poses.read_poses, value for value, or None
(then read_poses reads the file, so errors name the line as always)."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.io.poses import read_poses
from seg2pose.safety import tracks as T
from seg2pose.safety.tracks import load_tracks, read_poses_fast


def write(path, header, rows, newline_at_end=True):
    text = header + "\n" + "\n".join(rows) + ("\n" if newline_at_end else "")
    path.write_text(text)
    return path


def same_table(a, b):
    for k in ("frame", "track_id", "cls", "xyz", "heading", "size", "source", "r90"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is None:
            continue
        assert x.dtype == y.dtype and x.shape == y.shape, k
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=k)  # NaN where NaN, else bit equal
        else:
            assert (x == y).all(), k


def random_rows(rng, n_frames=40, sizes=True, r90=True):
    rows = []
    for f in range(n_frames):
        for tid in rng.choice(np.arange(-2, 30), size=rng.integers(0, 6), replace=False):
            cls = rng.choice(["car", "pedestrian", " bicyclist ", "Truck"])
            x, y, z = rng.normal(0, 300, 3)
            h = "nan" if rng.random() < 0.2 else repr(float(rng.uniform(-4, 4)))
            r = [str(f), str(int(tid)), cls, repr(float(x)), repr(float(y)), repr(float(z)), h]
            if sizes:
                r += ["nan" if rng.random() < 0.1 else repr(float(rng.uniform(0.2, 12))) for _ in range(3)]
            if r90:
                r.append("nan" if rng.random() < 0.1 else repr(float(rng.uniform(0, 3))))
            rows.append(",".join(r))
    return rows


@pytest.mark.parametrize("sizes,r90", [(True, True), (True, False), (False, True), (False, False)])
@pytest.mark.parametrize("seed", [0, 1])
def test_same_table_as_read_poses(tmp_path, monkeypatch, sizes, r90, seed):
    header = "frame,track_id,class,x,y,z,heading" + (",l,w,h" if sizes else "") + (",r90_m" if r90 else "")
    rows = random_rows(np.random.default_rng(seed), sizes=sizes, r90=r90)
    p = write(tmp_path / "poses.csv", header, rows, newline_at_end=bool(seed))
    monkeypatch.setattr(T, "FAST_LINES", 1)  # blocks of a few lines: many blocks
    fast = read_poses_fast(p)
    assert fast is not None
    same_table(fast, read_poses(p))
    same_table(read_poses_fast(p, workers=2), fast)  # blocks parsed in two processes


BAD = {  # a row read_poses rejects, and what it says
    "frames out of order": ("5,1,car,0,0,0,0\n4,2,car,0,0,0,0", "frames must be in order"),
    "duplicate row": ("5,1,car,0,0,0,0\n5,1,car,1,0,0,0", "duplicate row"),
    "not a number": ("5,1,car,x,0,0,0", "expected numbers"),
    "far away": ("5,1,car,1e7,0,0,0", "x, y, z must be finite"),
    "infinite heading": ("5,1,car,0,0,0,inf", "heading must be finite"),
    "fields": ("5,1,car,0,0,0", "expected 7 fields"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_errors_are_read_poses_errors(tmp_path, case):
    body, message = BAD[case]
    p = tmp_path / "poses.csv"
    p.write_text("frame,track_id,class,x,y,z,heading\n" + body + "\n")
    assert read_poses_fast(p) is None
    with pytest.raises(InputError, match=message):
        load_tracks(p, fps=30)


@pytest.mark.parametrize("row", ['5,1,"car",0,0,0,0', "5, 1,car,0,0,0,0", "+5,1,car,0,0,0,0",
                                 "00000000000000000005,1,car,0,0,0,0", "5,1_0,car,0,0,0,0",
                                 "5,1,car,0,0,0,0\r"])
def test_unusual_spellings_left_to_read_poses(tmp_path, row):
    """Quoting, spaces or a sign around the integers, 20 digits, '1_0', CR line ends: the
    same table as read_poses ('+5'), or not vouched for (None) and read_poses decides (a
    table or its error)."""
    p = tmp_path / "poses.csv"
    p.write_bytes(("frame,track_id,class,x,y,z,heading\n" + row + "\n").encode())
    fast = read_poses_fast(p)
    if fast is not None:
        same_table(fast, read_poses(p))
        return
    try:
        want = read_poses(p)
    except InputError as e:
        with pytest.raises(InputError, match=str(e.args[0])[:20]):
            load_tracks(p, fps=30)
    else:
        got, _ = load_tracks(p, fps=30)
        assert len(got) == len(want)


def test_source_column_left_to_read_poses(tmp_path):
    p = write(tmp_path / "poses.csv", "frame,track_id,class,x,y,z,heading,l,w,h,source",
              ["0,1,car,0,0,0,0,4,2,1.5,keyframe"])
    assert read_poses_fast(p) is None
    assert len(load_tracks(p, fps=30)[0]) == 1


@pytest.mark.parametrize("body", ["", "0,1,car,0,0,0,0\n\n1,1,car,0,0,0,0\n"])
def test_no_rows_or_blank_lines_left_to_read_poses(tmp_path, body):
    p = tmp_path / "poses.csv"
    p.write_text("frame,track_id,class,x,y,z,heading\n" + body)
    assert read_poses_fast(p) is None
    assert len(load_tracks(p, fps=30)[0]) == len(read_poses(p))
