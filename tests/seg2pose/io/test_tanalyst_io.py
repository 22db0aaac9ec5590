"""T-Analyst tracks CSV: exact round trips, time stamps <-> frames, bad input naming the line."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.core.errors import InputError
from seg2pose.io.tanalyst import (
    TAnalystTable,
    format_tanalyst,
    format_time,
    frames_to_times,
    parse_tanalyst,
    parse_time,
    read_tanalyst,
    times_to_frames,
    write_tanalyst,
)

HEADER = "Detection ID;Type of road user;Road user ID;X (m);Y (m);Time Stamp"
SAMPLE = "\n".join([HEADER,
                    "1;Car;3;12,5;-4,25;00:01:23.467",
                    "2;Pedestrian;7;0,125;3;00:01:23.467",
                    "3;Car;3;13,75;-4,5;00:01:23.533",
                    "4;Pedestrian;7;0,25;3,0625;00:01:23.600"]) + "\n"


def test_sample_reads_as_written_and_writes_back_identically(tmp_path):
    t = parse_tanalyst(SAMPLE)
    assert t.detection_id.tolist() == [1, 2, 3, 4] and t.road_user_id.tolist() == [3, 7, 3, 7]
    assert list(t.road_user_type) == ["Car", "Pedestrian", "Car", "Pedestrian"]
    assert t.xy.tolist() == [[12.5, -4.25], [0.125, 3.0], [13.75, -4.5], [0.25, 3.0625]]
    assert t.time_ms.tolist() == [83467, 83467, 83533, 83600] and t.decimal == ","
    assert t.lines.tolist() == [2, 3, 4, 5]
    assert format_tanalyst(t) == SAMPLE
    write_tanalyst(tmp_path / "t.csv", t)
    assert (tmp_path / "t.csv").read_text() == SAMPLE and read_tanalyst(tmp_path / "t.csv") == t


def test_time_stamps_and_frames_by_hand():
    assert parse_time("00:01:23.467") == 83467 and parse_time("10:00:00,001") == 36_000_001
    assert format_time(83467) == "00:01:23.467" and format_time(100 * 3600_000) == "100:00:00.000"
    t = parse_tanalyst(SAMPLE)
    # 15 fps from 00:01:23.400: 0.067 s = 1.005 frames -> 1; 0.133 s -> 2; 0.2 s -> 3
    assert times_to_frames(t, 15.0, parse_time("00:01:23.400")).tolist() == [1, 1, 2, 3]
    assert frames_to_times(np.array([0, 1, 2, 3]), 15.0, 83400).tolist() == [83400, 83467, 83533, 83600]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 50), st.floats(-1e4, 1e4, allow_nan=False),
                          st.floats(-1e4, 1e4, allow_nan=False), st.integers(0, 10**6)),
                min_size=0, max_size=30),
       st.sampled_from([",", "."]), st.sampled_from([7.5, 13.333, 15.0, 25.0, 29.97, 60.0]),
       st.integers(0, 40 * 3600_000))
def test_table_text_table_round_trip_is_exact(rows, decimal, fps, start):
    rows = sorted(rows, key=lambda r: (r[0], r[3]))
    rows = [r for i, r in enumerate(rows) if i == 0 or rows[i - 1][0] != r[0] or rows[i - 1][3] != r[3]]
    frames = np.array([r[3] for r in rows], np.int64)
    times = frames_to_times(frames, fps, start)
    t = TAnalystTable(np.arange(1, len(rows) + 1), [["Car", "Bicycle"][r[0] % 2] for r in rows],
                      [r[0] for r in rows], np.array([[r[1], r[2]] for r in rows]).reshape(-1, 2),
                      times, decimal=decimal)
    text = format_tanalyst(t)
    back = parse_tanalyst(text)
    assert back == t and format_tanalyst(back) == text
    assert "e" not in text.split("\n", 1)[1].lower().replace("bicycle", "")  # no 1e-05 style
    assert np.array_equal(times_to_frames(back, fps, start), frames)  # frames survive the ms rounding


@pytest.mark.parametrize("bad_line, line, message", [
    ("5;Car;3;13,75;-4.5;00:01:23.600", 6, "mixed decimal separators"),
    ("5;Car;3;13,75;-4,5;00:01:23.500", 6, "not after its previous one.*line 4.*out of order"),
    ("5;Car;3;13,75;-4,5;00:01:23.533", 6, "not after its previous one"),
    ("5;Car;3;13,75;-4,5;1:23.6", 6, "expected a time stamp HH:MM:SS.mmm"),
    ("5;Car;3;13,75;x;00:01:24.000", 6, "expected a number, got 'x'"),
    ("5;Car;3;13,75;00:01:24.000", 6, "expected 6 ';'-separated fields, got 5"),
    ("5;Car;three;1;1;00:01:24.000", 6, "field .Road user ID.: expected an integer"),
    ("2;Car;9;1;1;00:01:24.000", 6, "Detection ID 2 also on line 3"),
    ("5;Truck;3;1;1;00:01:24.000", 6, "road user 3 is 'Truck' here but 'Car' on line 2"),
])
def test_bad_rows_name_the_line(tmp_path, bad_line, line, message):
    p = tmp_path / "bad.csv"
    p.write_text(SAMPLE + bad_line + "\n")
    with pytest.raises(InputError, match=message) as e:
        read_tanalyst(p)
    assert str(e.value).startswith(f"{p}:{line}:")


def test_bad_header_and_frame_rate_errors_name_the_line(tmp_path):
    p = tmp_path / "h.csv"
    p.write_text(SAMPLE.replace("Time Stamp", "Time"))
    with pytest.raises(InputError, match="expected the header") as e:
        read_tanalyst(p)
    assert e.value.line == 1
    p.write_text(SAMPLE)
    t = read_tanalyst(p)
    with pytest.raises(InputError, match="before the video's start") as e:
        times_to_frames(t, 15.0, parse_time("00:01:23.500"), file=p)
    assert e.value.line == 2
    # at 10 fps 00:01:23.467 is 0.33 frames off a frame: the frame rate is wrong
    with pytest.raises(InputError, match="0.33 frames from the nearest frame at 10 fps") as e:
        times_to_frames(t, 10.0, parse_time("00:01:23.400"), file=p)
    assert str(e.value).startswith(f"{p}:2:")


def test_dot_decimals_and_windows_line_ends_read():
    text = SAMPLE.replace(",", ".").replace("\n", "\r\n")
    t = parse_tanalyst("\ufeff" + text)
    assert t.decimal == "." and t == parse_tanalyst(SAMPLE)
    assert format_tanalyst(t, decimal=",") == SAMPLE
