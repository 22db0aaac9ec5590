"""Default heights (`s2p heights`): the bisection writes them into scene.json."""

import json

import numpy as np

from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.scene import ClassSpec, Scene, load_scene
from seg2pose.structures.masks import encode


def test_heights_bisection_writes_scene_json(tmp_path):
    """A camera over flat ground; pedestrians and cars as exact box masks; ``s2p heights``
    moves the default heights so that about half the normal positions are closer."""
    import cv2

    from seg2pose.method.heights import update_default_heights

    cam = Camera.look_at("c0", [0, -15, 8], [0, 10, 0], 800.0, 960, 540)
    pts = np.array([[x, y, 0.0] for x in range(-20, 21, 4) for y in range(-10, 41, 4)], float)
    s = Scene(root=tmp_path, name="t", fps=10.0, rig=Rig({"c0": cam}, {}, "r"), ground_points=pts,
              classes=[ClassSpec(1, "pedestrian", 0.3), ClassSpec(3, "car", 1.4)],
              splits={"train": (0, 39)})
    s.save()
    rng = np.random.default_rng(0)
    rows, masks = [], []
    for f in range(40):
        for k, (cname, cid, (l, w, h)) in enumerate([("pedestrian", 1, (0.5, 0.5, 1.8)),
                                                      ("car", 3, (4.5, 1.8, 1.5))]):
            x, y, hd = rng.uniform(-8, 8), rng.uniform(0, 30), rng.uniform(-3, 3)
            c, sn = np.cos(hd), np.sin(hd)
            corners = np.array([(x + c * a - sn * b, y + sn * a + c * b, z) for a in (-l / 2, l / 2)
                                for b in (-w / 2, w / 2) for z in (0, h)])
            uv, _, _ = cam.project_points(corners)
            m = np.zeros((540, 960), np.uint8)
            cv2.fillConvexPoly(m, cv2.convexHull(np.round((uv - 0.5) * 16).astype(np.int32)), 1, shift=4)
            rows.append((f, k, cname, x, y, hd, l, w, h))
            masks.append((f, k, cid, encode(m)))
    f, k, cn, x, y, hd, l, w, h = zip(*rows)
    write_poses(tmp_path / "gt" / "poses.csv",
                PoseTable(f, k, np.array(cn, object), np.column_stack([x, y, np.zeros(len(x))]), hd,
                          np.column_stack([l, w, h])))
    f, k, cid, rl = zip(*masks)
    (tmp_path / "masks").mkdir()
    write_mots(tmp_path / "masks" / "c0.txt", MaskTable(f, k, cid, 540, 960, list(rl)))
    lines = []
    rep = update_default_heights(load_scene(tmp_path), "train", "bbox", log=lines.append)
    assert rep["pedestrian"]["n"] == 40 and rep["car"]["n"] == 40
    for c in ("pedestrian", "car"):
        assert 0.4 <= rep[c]["closer_share"] <= 0.6
    # a box's projected bbox centre sits near its middle: heights near half the box height
    assert 0.6 < rep["pedestrian"]["new"] < 1.2 and 0.5 < rep["car"]["new"] < 1.0
    d = json.loads((tmp_path / "scene.json").read_text())
    assert [c["default_height"] for c in d["classes"]] == [rep["pedestrian"]["new"], rep["car"]["new"]]
    assert any("pedestrian: 0.300 m ->" in ln for ln in lines)
