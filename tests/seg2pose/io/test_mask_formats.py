"""Mask files (MOTS txt, COCO json, PNG folders): exact round trips, streaming, bad input
naming file and line, and `s2p convert-masks`."""

import json

import numpy as np
import pytest
from io_fixtures import RLE, H, W, masks_table, same_masks, write

from seg2pose.core.errors import InputError
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import iter_mots, read_mots, write_mots
from seg2pose.io.png import read_png_folder, write_png_folder
from seg2pose.structures.masks import decode

# --- round trips ---------------------------------------------------------------------------------

def test_mots_round_trip_and_streaming(tmp_path):
    t = masks_table()
    write_mots(tmp_path / "m.txt", t)
    same_masks(read_mots(tmp_path / "m.txt"), t)
    frames = [f for f, _ in iter_mots(tmp_path / "m.txt")]
    assert frames == [0, 1, 3]
    assert len(read_mots(tmp_path / "m.txt", frame_range=(1, 2))) == 3


def test_coco_round_trip(tmp_path):
    t = masks_table()
    t.score = np.linspace(0.5, 1.0, len(t))
    write_coco(tmp_path / "m.json", t)
    r = read_coco(tmp_path / "m.json")
    same_masks(r, t)
    assert np.array_equal(r.score, t.score)
    # a COCO dataset object with uncompressed counts and image -> frame ids
    m = np.zeros((H, W), np.uint8)
    m[2:5, 3:4] = 1
    counts = [3 * H + 2, 3, H * W - 3 * H - 5]
    data = {"images": [{"id": 7, "frame_id": 42}],
            "annotations": [{"image_id": 7, "category_id": 3,
                             "segmentation": {"size": [H, W], "counts": counts}}]}
    (tmp_path / "d.json").write_text(json.dumps(data))
    r = read_coco(tmp_path / "d.json")
    assert r.frame.tolist() == [42] and r.track_id.tolist() == [-1] and r.class_id.tolist() == [3]
    assert np.array_equal(decode(r.rles[0], H, W), m)


def test_png_folder_round_trip_exact(tmp_path):
    t = masks_table(overlap=False)
    written = write_png_folder(tmp_path / "png", t)
    assert [p.name for p in written] == ["000000.png", "000001.png", "000003.png"]
    r = read_png_folder(tmp_path / "png")
    same_masks(r, t, ordered=False)
    import cv2
    img = cv2.imread(str(written[0]), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and set(np.unique(img)) == {0, 1005, 2006, 3007}


def test_png_rejects_untracked(tmp_path):
    t = masks_table()
    t.track_id[0] = -1
    with pytest.raises(InputError, match="track id -1"):
        write_png_folder(tmp_path / "png", t)


# --- bad input names file, line/field and what was expected -------------------------------------


@pytest.mark.parametrize("text,match", [
    ("0 1 1 2 3\n", r"m.txt:1: expected 6 fields"),
    (f"0 1 1 2 3 {RLE}\n0 1 1 2 4 {RLE}\n", r"m.txt:2: image size 2x4 differs"),
    (f"0 1 1 2 3 {RLE}\n0 1 1 3 3 {RLE}\n", r"m.txt:2: image size 3x3 differs"),
    (f"0 1 1 4 3 {RLE}\n", r"m.txt:1: RLE covers 6 pixels but height\*width = 12"),
    (f"0 1 9 2 3 {RLE}\n", r"m.txt:1: unknown class_id 9"),
    (f"5 1 1 2 3 {RLE}\n# c\n4 1 1 2 3 {RLE}\n", r"m.txt:3: frame 4 comes after frame 5"),
    (f"0 1 1 0 3 {RLE}\n", r"m.txt:1: non-positive image size"),
    ("0 1 1 2 3 ~~\n", r"m.txt:1: .*COCO alphabet"),
    ("a 1 1 2 3 x\n", r"m.txt:1: expected integers"),
])
def test_mots_bad_input(tmp_path, text, match):
    p = write(tmp_path, "m.txt", text)
    with pytest.raises(InputError, match=match):
        read_mots(p, known_classes={1, 2, 3})


def test_coco_bad_input(tmp_path):
    rec = {"frame": 0, "category_id": 1, "segmentation": {"size": [2, 3], "counts": RLE}}
    cases = [
        ({**rec, "category_id": 9}, r"field '\[0\].category_id': unknown class 9"),
        ({**rec, "segmentation": {"size": [4, 3], "counts": RLE}}, r"field '\[0\].segmentation.counts': RLE covers 6"),
        ({**rec, "frame": "a"}, r"field '\[0\].frame': expected an integer"),
        ({**rec, "segmentation": [[1, 2, 3]]}, r"field '\[0\].segmentation'"),
    ]
    for r, match in cases:
        p = tmp_path / "c.json"
        p.write_text(json.dumps([rec, r][1:]))
        with pytest.raises(InputError, match=match):
            read_coco(p, known_classes={1, 2, 3})


# --- commands ------------------------------------------------------------------------------------

def test_cli_convert_masks_round_trip(tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    t = masks_table(overlap=False)
    write_mots(tmp_path / "a.txt", t)
    run = CliRunner().invoke
    r = run(app, ["convert-masks", str(tmp_path / "a.txt"), "-o", str(tmp_path / "b.json"), "--format", "coco"])
    assert r.exit_code == 0, r.output
    assert "9 masks in 3 frames (32x24)" in r.output
    assert run(app, ["convert-masks", str(tmp_path / "b.json"), "-o", str(tmp_path / "png"),
                     "-f", "png"]).exit_code == 0
    assert run(app, ["convert-masks", str(tmp_path / "png"), "-o", str(tmp_path / "c.txt"),
                     "-f", "mots"]).exit_code == 0
    same_masks(read_mots(tmp_path / "c.txt"), t, ordered=False)
    r = run(app, ["convert-masks", str(tmp_path / "png"), "-o", str(tmp_path / "c.txt"), "-f", "mots"])
    assert r.exit_code != 0 and "--force" in str(r.exception)


def test_iter_mots_blocks_keep_frames_whole(tmp_path, monkeypatch):
    import seg2pose.io.mots as M

    t = masks_table()
    write_mots(tmp_path / "m.txt", t)
    monkeypatch.setattr(M, "_BLOCK", 2)  # blocks end only at frame boundaries
    got = [(f, len(x), x.frame.tolist()) for f, x in iter_mots(tmp_path / "m.txt")]
    assert got == [(0, 3, [0, 0, 0]), (1, 3, [1, 1, 1]), (3, 3, [3, 3, 3])]
    lines = (tmp_path / "m.txt").read_text().splitlines()
    parts = lines[7].split()
    lines[7] = " ".join(parts[:5] + [RLE])  # a 2x3 mask's runs on a 24x32 line
    (tmp_path / "m.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"m.txt:8: RLE covers 6 pixels but height\*width = 768"):
        list(iter_mots(tmp_path / "m.txt"))
