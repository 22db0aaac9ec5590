"""Fuzzing of the masks readers and writers (hypothesis): MOTS text, COCO JSON, PNG folders and
``s2p convert-masks`` between them. Near-valid and random inputs end in the project's one-line
error or parse; what a reader accepts, its writer writes back exactly; valid files parse to the
values written; a conversion's output is accepted by the reader of its format."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from fuzz_fixtures import (
    FUZZ,
    FUZZ_FILES,
    folder,
    fuzz_file,
    json_values,
    mutate_json,
    mutate_text,
    only_s2p_errors,
    text_like,
)
from hostile_fixtures import H, W, write_scene
from hypothesis import given
from hypothesis import strategies as st
from io_fixtures import RLE, same_masks
from io_fixtures import H as IO_H
from io_fixtures import W as IO_W

from seg2pose.core.errors import S2PError
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.png import read_png_folder, write_png_folder
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import read_ground_points
from seg2pose.structures.masks import decode, encode


@st.composite
def mask_tables(draw):
    """Non-overlapping box masks, one per (frame, track), frames in order."""
    n_frames = draw(st.integers(1, 4))
    fr, tid, cid, rles = [], [], [], []
    for f in sorted(draw(st.lists(st.integers(0, 10 ** 6), min_size=n_frames, max_size=n_frames,
                                  unique=True))):
        for k in range(draw(st.integers(1, 3))):
            m = np.zeros((H, W), np.uint8)
            x0 = 20 * k + draw(st.integers(0, 8))
            y0 = draw(st.integers(0, H - 2))
            m[y0:y0 + draw(st.integers(1, 10)), x0:x0 + draw(st.integers(1, 10))] = 1
            fr.append(f)
            tid.append(10 * k + draw(st.integers(0, 9)))  # unique within the frame
            cid.append(draw(st.integers(1, 3)))
            rles.append(encode(m))
    return MaskTable(fr, tid, cid, H, W, rles)


def same_table(a: MaskTable, b: MaskTable) -> bool:
    if len(a) != len(b) or (a.height, a.width) != (b.height, b.width):
        return False
    if not (np.array_equal(a.frame, b.frame) and np.array_equal(a.track_id, b.track_id)
            and np.array_equal(a.class_id, b.class_id)):
        return False
    return all(np.array_equal(decode(x, a.height, a.width), decode(y, b.height, b.width))
               for x, y in zip(a.rles, b.rles))


@FUZZ
@given(mask_tables())
def test_mots_and_coco_round_trip(t):
    with folder() as d:
        write_mots(d / "m.txt", t)
        assert same_table(read_mots(d / "m.txt"), t)
        write_coco(d / "m.json", t)
        assert same_table(read_coco(d / "m.json"), t)


@FUZZ
@given(mask_tables())
def test_png_round_trip(t):
    with folder() as d:
        write_png_folder(d / "png", t)
        r = read_png_folder(d / "png")
        order = np.lexsort((t.class_id * 1000 + t.track_id, t.frame))  # a frame's ids in order
        assert same_table(r, t.take(order))


def _valid_masks(d: Path) -> MaskTable:
    return read_mots(write_scene(d, frames=3, users=2).masks_path("c0"))


@FUZZ
@given(st.data())
def test_mots_near_valid(data):
    with folder() as d:
        t = _valid_masks(d)
        p = d / "m.txt"
        write_mots(p, t)
        p.write_text(mutate_text(data, p.read_text(), None))
        r = only_s2p_errors(lambda: read_mots(p, known_classes=[1, 2, 3]))
        if r is not None and len(r):
            assert (np.diff(r.frame) >= 0).all() and (r.frame >= 0).all()
            tracked = r.track_id >= 0
            keys = set(zip(r.frame[tracked].tolist(), r.track_id[tracked].tolist()))
            assert len(keys) == int(tracked.sum())


@FUZZ
@given(st.data())
def test_coco_near_valid(data):
    with folder() as d:
        t = _valid_masks(d)
        write_coco(d / "m.json", t)
        obj = json.loads((d / "m.json").read_text())
        (d / "m.json").write_text(mutate_json(data, obj))
        r = only_s2p_errors(lambda: read_coco(d / "m.json"))
        if r is not None and len(r):
            assert (r.frame >= 0).all() and r.height > 0 and r.width > 0


@FUZZ
@given(st.data())
def test_png_near_valid(data):
    import cv2

    with folder() as d:
        t = _valid_masks(d)
        paths = write_png_folder(d / "png", t)
        p = data.draw(st.sampled_from(paths))
        kind = data.draw(st.sampled_from(["truncate", "flip", "rgb", "float", "size", "bytes"]))
        raw = p.read_bytes()
        if kind == "truncate":
            p.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1))])
        elif kind == "flip":
            i = data.draw(st.integers(0, len(raw) - 1))
            p.write_bytes(raw[:i] + bytes([raw[i] ^ 0xFF]) + raw[i + 1:])
        elif kind == "rgb":
            cv2.imwrite(str(p), np.zeros((H, W, 3), np.uint8))
        elif kind == "float":
            p.write_bytes(cv2.imencode(".tiff", np.zeros((H, W), np.float32))[1].tobytes())
        elif kind == "size":
            cv2.imwrite(str(p), np.zeros((W, H), np.uint16))
        else:
            p.write_bytes(data.draw(st.binary(max_size=200)))
        only_s2p_errors(lambda: read_png_folder(d / "png"))


FILE_READERS = {"g.csv": read_ground_points, "p.csv": read_poses, "m.txt": read_mots,
                "m.json": read_coco}


@FUZZ
@given(st.binary(max_size=400), st.sampled_from(sorted(FILE_READERS)))
def test_file_readers_random_bytes(blob, name):
    """Ground points, poses.csv, MOTS and COCO files of random bytes."""
    with folder() as d:
        (d / name).write_bytes(blob)
        only_s2p_errors(lambda: FILE_READERS[name](d / name))


@FUZZ_FILES
@given(text_like())
def test_fuzz_mots(tmp_path, data):
    fuzz_file(tmp_path, "m.txt", data, lambda p: read_mots(p, {1, 2, 3}), write_mots, same_masks)


@FUZZ_FILES
@given(st.one_of(text_like(), st.binary(max_size=40).map(lambda b: b"0 1 1 2 3 " + b + b"\n")))
def test_fuzz_mots_rle(tmp_path, data):
    fuzz_file(tmp_path, "m.txt", data, read_mots, write_mots, same_masks)


@FUZZ_FILES
@given(text_like())
def test_fuzz_coco(tmp_path, data):
    fuzz_file(tmp_path, "c.json", data, read_coco)


@FUZZ_FILES
@given(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 99), st.integers(1, 3),
                          st.integers(0, IO_H - 1), st.integers(0, IO_W - 1), st.integers(1, 6),
                          st.integers(1, 6)), min_size=1, max_size=10,
                unique_by=lambda b: (b[0], b[1])))  # one mask per road user and frame
def test_valid_mots_parse_exactly(tmp_path, boxes):
    boxes = sorted(boxes, key=lambda b: b[0])
    masks = []
    for _, _, _, y, x, h, w in boxes:
        m = np.zeros((IO_H, IO_W), np.uint8)
        m[y:y + h, x:x + w] = 1
        masks.append(m)
    lines = [f"{f} {t} {c} {IO_H} {IO_W} {encode(m).decode()}" for (f, t, c, *_), m in zip(boxes, masks)]
    (tmp_path / "m.txt").write_text("\n".join(lines) + "\n")
    got = read_mots(tmp_path / "m.txt")
    assert got.frame.tolist() == [b[0] for b in boxes] and got.track_id.tolist() == [b[1] for b in boxes]
    assert got.class_id.tolist() == [b[2] for b in boxes] and (got.height, got.width) == (IO_H, IO_W)
    for r, m in zip(got.rles, masks):
        np.testing.assert_array_equal(decode(r, IO_H, IO_W), m)


@FUZZ_FILES
@given(json_values, st.sampled_from(["frame", "category_id", "segmentation", "track_id", "score",
                                     "image_id"]))
def test_fuzz_coco_structured(tmp_path, value, key):
    rec = {"frame": 0, "category_id": 1, "segmentation": {"size": [2, 3], "counts": RLE}}
    rec[key] = value
    for data in ([rec], {"annotations": [rec], "images": [value]}, value):
        fuzz_file(tmp_path, "c.json", json.dumps(data).encode(), read_coco)


@FUZZ_FILES
@given(st.binary(max_size=200))
def test_fuzz_png(tmp_path, data):
    (tmp_path / "png").mkdir(exist_ok=True)
    (tmp_path / "png" / "000001.png").write_bytes(data)
    try:
        read_png_folder(tmp_path / "png")
    except S2PError:
        pass


# --- s2p convert-masks: near-valid input in any format, output read by its format's reader ----

@FUZZ
@given(st.data(), st.sampled_from(["mots", "coco"]), st.sampled_from(["mots", "coco", "png"]))
def test_convert_masks_near_valid(data, src_fmt, out_fmt):
    """``s2p convert-masks``: a damaged input is refused in one line with nothing written; an
    accepted one is written in a form its format's reader accepts, exactly for MOTS and COCO
    (a PNG holds one id per pixel: overlapping masks lose the covered pixels)."""
    from seg2pose.cli.scene import convert_masks_cmd

    with folder() as d:
        t = _valid_masks(d)
        src = d / ("in.txt" if src_fmt == "mots" else "in.json")
        (write_mots if src_fmt == "mots" else write_coco)(src, t)
        if src_fmt == "mots":
            src.write_text(mutate_text(data, src.read_text(), None))
        else:
            src.write_text(mutate_json(data, json.loads(src.read_text())))
        out = d / {"mots": "out.txt", "coco": "out.json", "png": "out"}[out_fmt]
        got = only_s2p_errors(lambda: convert_masks_cmd(src, out, out_fmt, src_fmt, False))
        if not out.exists():
            return  # refused (or nothing to hold: an empty PNG folder is not made)
        assert got is None
        table = read_mots(src) if src_fmt == "mots" else read_coco(src)
        back = {"mots": read_mots, "coco": read_coco, "png": read_png_folder}[out_fmt](out)
        if out_fmt != "png":
            same_masks(back, table)
        else:
            assert set(back.frame.tolist()) <= set(table.frame.tolist())
