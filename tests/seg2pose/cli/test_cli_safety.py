"""`s2p conflicts`: inputs (poses.csv with r90_m, T-Analyst), one-line errors, atomic output
that is not overwritten without --force."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.tanalyst import TAnalystTable, frames_to_times, write_tanalyst


def s2p(capsys, *argv):
    from seg2pose.cli import main

    try:
        main(list(argv))
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def crossing_poses(r90: float | None = None):
    """Two cars crossing at right angles, 10 m/s, 2 s apart (PET 1.42 s), 30 fps."""
    t = np.arange(0, 8, 1 / 30)
    f = np.arange(len(t))
    n = len(t)
    z = np.zeros(n)
    table = PoseTable(np.r_[f, f], np.r_[np.ones(n), 2 * np.ones(n)], np.array(["car"] * 2 * n, object),
                      np.c_[np.r_[10 * (t - 3), z], np.r_[z, 10 * (t - 5)], np.zeros(2 * n)],
                      np.r_[z, np.full(n, np.pi / 2)], np.tile([4.0, 1.8, 1.5], (2 * n, 1))).sorted()
    return table


def write_with_r90(path, table, r90):
    write_poses(path, table)
    lines = path.read_text().splitlines()
    lines = [lines[0] + ",r90_m"] + [ln + f",{r90}" for ln in lines[1:]]
    path.write_text("\n".join(lines) + "\n")


def read_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_conflicts_from_poses_csv_with_intervals(tmp_path, capsys):
    p = tmp_path / "poses.csv"
    write_with_r90(p, crossing_poses(), 0.3)
    out = tmp_path / "conflicts.csv"
    pet = tmp_path / "pet.csv"
    code, so, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--draws", "40",
                       "--pet-only", str(pet))
    assert code == 0, se
    assert read_rows(out) == []  # no collision course: no SSAM conflict, a PET-only encounter
    rows = read_rows(pet)
    assert len(rows) == 1 and rows[0]["type"] == "crossing" and rows[0]["pet_only"] == "1"
    r = rows[0]
    assert float(r["pet_s"]) == pytest.approx(1.42, abs=1e-3)
    assert float(r["pet_lo_s"]) < 1.42 < float(r["pet_hi_s"])  # 0.3 m of error: an interval around it
    assert float(r["pet_found_share"]) > 0.9
    # not overwritten without --force; one line, no traceback
    code, so, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30")
    assert code == 2 and "--force" in se and "Traceback" not in se


def test_conflicts_without_fps_and_bad_r90_are_one_line(tmp_path, capsys):
    p = tmp_path / "poses.csv"
    write_with_r90(p, crossing_poses(), 0.3)
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(tmp_path / "c.csv"))
    assert code == 2 and "--fps" in se and len(se.strip().splitlines()) == 1
    lines = p.read_text().splitlines()
    lines[5] = lines[5].rsplit(",", 1)[0] + ",-2"
    p.write_text("\n".join(lines) + "\n")
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(tmp_path / "c.csv"), "--fps", "30")
    assert code == 2 and f"{p}:6" in se and "r90_m" in se and len(se.strip().splitlines()) == 1


def test_conflicts_heading90(tmp_path, capsys):
    """--heading90: intervals that also turn the footprints; a bad value or a class without
    one is one line naming the option."""
    p = tmp_path / "poses.csv"
    write_with_r90(p, crossing_poses(), 0.3)
    out = tmp_path / "c.csv"
    for bad in ("car=400", "pedestrian=10"):
        code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--heading90", bad)
        assert code == 2 and "--heading90" in se and len(se.strip().splitlines()) == 1, se
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--heading90",
                      "car=20", "--draws", "40", "--all-pairs")
    assert code == 0, se
    r = read_rows(out)[0]
    assert float(r["pet_lo_s"]) <= float(r["pet_s"]) <= float(r["pet_hi_s"])


def test_conflicts_from_tanalyst_with_class_radius(tmp_path, capsys):
    """T-Analyst tracks: positions and times only; headings from motion, sizes by class
    (cars 4.5 x 1.8 m, seg2pose.io.scene's), frames from the time stamps at --fps."""
    table = crossing_poses()
    ms = frames_to_times(table.frame, 30, 3_600_000)
    ta = TAnalystTable(np.arange(1, len(table) + 1), np.array(["Car"] * len(table), object),
                       table.track_id, table.xyz[:, :2], ms)
    p = tmp_path / "tracks.csv"
    write_tanalyst(p, ta)
    out = tmp_path / "c.csv"
    code, so, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--start",
                       "01:00:00.000", "--r90", "car=0.5", "--draws", "20", "--all-pairs")
    assert code == 0, se
    r = read_rows(out)[0]
    # 4.5 m long cars: the first's rear leaves at 3 + (2.25 + 0.9) / 10 s, the second's front
    # enters at 5 - (2.25 + 0.9) / 10 s
    assert float(r["pet_s"]) == pytest.approx(2 - 0.63, abs=0.005)
    assert r["pet_lo_s"] != ""


def test_conflicts_frames_range(tmp_path, capsys):
    """--frames A:B: only those frames (the crossing's second car reaches the spot after
    frame 120, so frames 0:120 hold no conflict); a reversed range is one line."""
    p = tmp_path / "poses.csv"
    write_poses(p, crossing_poses())
    out = tmp_path / "c.csv"
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--frames", "0:120")
    assert code == 0, se
    assert read_rows(out) == []
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--frames", "9:3",
                      "--force")
    assert code == 2 and "--frames" in se


def test_conflict_map_and_tct_chart_are_pictures(tmp_path, capsys):
    """--map and --tct-chart write PNG pictures (the crossing: one PET-only spot on the map)."""
    p = tmp_path / "poses.csv"
    write_poses(p, crossing_poses())
    m, t = tmp_path / "map.png", tmp_path / "tct.png"
    code, so, se = s2p(capsys, "conflicts", str(p), "-o", str(tmp_path / "c.csv"), "--fps", "30",
                       "--map", str(m), "--tct-chart", str(t))
    assert code == 0, se
    assert "0 conflicts" in so and "1 PET-only" in so
    for f in (m, t):
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("curve", ["10:0.5", "10:0.5,10:1.0", "10-0.5,50:1.5", "10:-1,50:1.5"])
def test_tct_curve_is_checked(tmp_path, capsys, curve):
    """--tct-curve takes at least two KMH:SECONDS points of distinct, non-negative speeds: one
    line naming the option otherwise (a lone point, a repeated speed, a wrong separator, a
    negative TA)."""
    p = tmp_path / "poses.csv"
    write_poses(p, crossing_poses())
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(tmp_path / "c.csv"), "--fps", "30",
                      "--tct-curve", curve)
    assert code == 2 and "--tct-curve" in se and "Traceback" not in se


@pytest.mark.parametrize("spread", ["2,2", "2,0,2", "a,b,c"])
def test_interval_spread_is_checked(tmp_path, capsys, spread):
    """--interval-spread takes three positive factors: one line naming the option otherwise."""
    p = tmp_path / "poses.csv"
    write_poses(p, crossing_poses())
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(tmp_path / "c.csv"), "--fps", "30", "--r90",
                      "car=0.3", "--interval-spread", spread)
    assert code == 2 and "--interval-spread" in se and "Traceback" not in se


def test_two_outputs_naming_one_file_are_refused(tmp_path, capsys):
    """-o and --map (or any two output options) naming one file: one line naming both options,
    nothing written (before, the set committed two builds to one name and one output was lost)."""
    p = tmp_path / "poses.csv"
    write_with_r90(p, crossing_poses(), 0.3)
    out = tmp_path / "c.csv"
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30", "--map", str(out))
    assert code == 2 and "-o" in se and "--map" in se and len(se.strip().splitlines()) == 1
    code, _, se = s2p(capsys, "conflicts", str(p), "-o", str(out), "--fps", "30",
                      "--pet-only", str(tmp_path / "p.csv"), "--tct-chart", str(tmp_path / "." / "p.csv"))
    assert code == 2 and "--pet-only" in se and "--tct-chart" in se
    assert sorted(x.name for x in tmp_path.iterdir()) == ["poses.csv"]
