"""Small hand-made files for the reader and writer tests (seg2pose/io) and their fuzzing
(tests/system/test_fuzz_*.py): a 24 x 32 mask table, a two-camera scene, a text-file writer."""

from __future__ import annotations

import numpy as np

from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.mots import MaskTable
from seg2pose.io.scene import ClassSpec, Scene
from seg2pose.structures.masks import encode

H, W = 24, 32


def masks_table(seed=0, overlap=True):
    """3 frames of small box masks (non-overlapping unless ``overlap``)."""
    rng = np.random.default_rng(seed)
    fr, tid, cid, rles = [], [], [], []
    for f in (0, 1, 3):
        for k in range(3):
            m = np.zeros((H, W), np.uint8)
            x0 = 10 * k + (0 if not overlap else int(rng.integers(0, 4)))
            y0 = int(rng.integers(0, 10))
            m[y0:y0 + int(rng.integers(2, 12)), x0:x0 + int(rng.integers(1, 9 if overlap else 10))] = 1
            fr.append(f)
            tid.append(k + 5)
            cid.append(1 + k % 3)
            rles.append(encode(m))
    return MaskTable(fr, tid, cid, H, W, rles)


def same_masks(a: MaskTable, b: MaskTable, ordered=True):
    assert (a.height, a.width) == (b.height, b.width)
    ka = list(zip(a.frame.tolist(), a.track_id.tolist(), a.class_id.tolist(), a.rles))
    kb = list(zip(b.frame.tolist(), b.track_id.tolist(), b.class_id.tolist(), b.rles))
    if not ordered:
        ka, kb = sorted(ka), sorted(kb)
    assert ka == kb


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


RLE = encode(np.ones((2, 3), np.uint8)).decode()


def make_scene(root, **kw):
    cam = Camera.look_at("c0", [0, -10, 5], [0, 0, 0], 500.0, 640, 480)
    cam1 = Camera.from_P("c1", Camera.look_at("x", [1, -10, 5], [0, 0, 0], 400.0, 320, 240).P, 320, 240)
    pts = np.array([[0, 0, 0], [1, 0, 0.1], [0, 1, 0.2], [5, 5, -0.3]], float)
    s = Scene(root=root, name="t", fps=10.0,
              rig=Rig({"c0": cam, "c1": cam1}, {"stereo": ["c0", "c1"]}, "r"),
              ground_points=pts,
              classes=[ClassSpec(1, "pedestrian", 0.8), ClassSpec(3, "car", 0.7)],
              splits={"train": (0, 9)}, extra={"k": 1}, **kw)
    s.save()
    return s
