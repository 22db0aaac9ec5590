"""The tiny hand-built scene most method and training tests share: three cameras 0.2 m apart
over a 30 x 20 m patch, road users driving straight, masks rendered as boxes (``make_tiny_scene``);
a fast training protocol for it (``tiny_config``) and a stand-in for the rough-model renderer
(``fake_rough_examples``, installed by the ``fake_rough`` fixture of tests/conftest.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from seg2pose.cli import main
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.scene import ClassSpec, Scene, load_scene
from seg2pose.structures.masks import encode
from seg2pose.training.config import TrainConfig

W, H = 320, 240
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]
SIZES = {"pedestrian": (0.6, 0.6, 1.8), "bicyclist": (1.8, 0.6, 1.7), "car": (4.4, 1.8, 1.5)}


def box_corners(xyz: np.ndarray, heading: float, lwh) -> np.ndarray:
    """(8, 3) corners of a box standing on xyz (metres) with the given heading."""
    l, w, h = lwh
    c, s = np.cos(heading), np.sin(heading)
    dx = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * l / 2
    dy = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * w / 2
    dz = np.array([0, 0, 0, 0, 1, 1, 1, 1]) * h
    return np.stack([xyz[0] + c * dx - s * dy, xyz[1] + s * dx + c * dy, xyz[2] + dz], axis=1)


def render_box(cam: Camera, xyz, heading, lwh) -> np.ndarray | None:
    uv, _, front = cam.project_points(box_corners(np.asarray(xyz, float), heading, lwh))
    if not front.all():
        return None
    img = np.zeros((cam.height, cam.width), np.uint8)
    hull = cv2.convexHull((uv - 0.5).round().astype(np.int32))
    cv2.fillConvexPoly(img, hull, 1)
    return img if img.any() else None


def make_tiny_scene(root: Path, frames: int = 40, n_users: int = 6, seed: int = 0,
                    splits=None, slope: float = 0.0) -> Scene:
    """Three cameras 0.2 m apart looking at a 30 x 20 m patch; road users driving straight.
    Writes scene.json, ground points, masks/<cam>.txt and gt/poses.csv; returns the Scene."""
    rng = np.random.default_rng(seed)
    cams = {}
    for k, off in enumerate((-0.2, 0.0, 0.2)):
        name = f"c{k}"
        cams[name] = Camera.look_at(name, np.array([0.0, off, 7.0]), np.array([14.0, 0.0, 0.0]),
                                    f=260.0, width=W, height=H)
    rig = Rig(cams, {"mono-1": ["c1"], "stereo-20": ["c0", "c2"], "tri-I": ["c0", "c1", "c2"]})
    gx, gy = np.meshgrid(np.arange(2.0, 32.0, 2.0), np.arange(-12.0, 13.0, 2.0))
    gz = slope * gx
    ground = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    if splits is None:
        splits = {"train": (0, frames // 2 - 1), "val": (frames // 2, 3 * frames // 4 - 1),
                  "test": (3 * frames // 4, frames - 1)}
    scene = Scene(root=root, name="tiny", fps=10.0, rig=rig, ground_points=ground,
                  classes=CLASSES, splits=dict(splits),
                  extra={"class_sizes": {k: list(v) for k, v in SIZES.items()}})
    scene.save(root)
    names = [c.name for c in CLASSES]
    users = []
    for tid in range(1, n_users + 1):
        cls = names[(tid - 1) % 3]
        p0 = np.array([rng.uniform(8, 24), rng.uniform(-5, 5)])
        hd = rng.uniform(-np.pi, np.pi)
        speed = {"pedestrian": 0.15, "bicyclist": 0.4, "car": 0.8}[cls]
        users.append((tid, cls, p0, hd, speed))
    gt_rows = []
    masks = {c: [] for c in cams}
    for f in range(frames):
        for tid, cls, p0, hd, speed in users:
            xy = p0 + f * speed * np.array([np.cos(hd), np.sin(hd)])
            z = float(scene.ground.height(xy[None])[0])
            xyz = np.array([xy[0], xy[1], z])
            gt_rows.append((f, tid, cls, xyz, hd, SIZES[cls]))
            cid = names.index(cls) + 1
            for cn, cam in cams.items():
                m = render_box(cam, xyz, hd, SIZES[cls])
                if m is not None:
                    masks[cn].append((f, tid, cid, encode(m)))
    for cn, rows in masks.items():
        write_mots(root / "masks" / f"{cn}.txt",
                   MaskTable([r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows],
                             H, W, [r[3] for r in rows]))
    gt = PoseTable([r[0] for r in gt_rows], [r[1] for r in gt_rows],
                   np.array([r[2] for r in gt_rows], object), np.array([r[3] for r in gt_rows]),
                   np.array([r[4] for r in gt_rows]), np.array([r[5] for r in gt_rows], float))
    write_poses(root / "gt" / "poses.csv", gt)
    return load_scene(root)


def fake_rough_examples(camera, ground, cls, n, rng, region_xy=None, occlusion=0.0):
    """Stand-in for seg2pose.synth.rough: boxes of the class size at random places/headings."""
    rles, xyz, hd = [], [], []
    while len(rles) < n:
        xy = np.array([rng.uniform(8, 24), rng.uniform(-6, 6)])
        p = np.array([xy[0], xy[1], float(ground.height(xy[None])[0])])
        h = rng.uniform(-np.pi, np.pi)
        m = render_box(camera, p, h, SIZES[cls])
        if m is not None:
            rles.append(encode(m))
            xyz.append(p)
            hd.append(h)
    return rles, np.array(xyz).reshape(-1, 3), np.array(hd)


def tiny_train_scene(tmp_path_factory) -> Scene:
    """The training tests' tiny scene (60 frames, 9 road users, seed 1)."""
    return make_tiny_scene(tmp_path_factory.mktemp("tiny_train"), frames=60, n_users=9, seed=1)


def tiny_config(**kw):
    """A training protocol for the tiny scene: a lite net, one run of 6 short epochs."""
    base = TrainConfig(arch="lite", runs=1, lr=2e-3, lr_schedule="cosine", batch_size=16,
                       batches_per_epoch=12, epochs=6, rough_per_class=24, rough_val_per_class=12,
                       share_classes=True)
    return base.replace(**kw)


def s2p(monkeypatch, capsys, *argv):
    """Run ``s2p ARGV`` in this process: (exit code, stdout, stderr)."""
    monkeypatch.setattr(sys, "argv", ["s2p", *map(str, argv)])
    with pytest.raises(SystemExit) as e:
        main()
    out = capsys.readouterr()
    return e.value.code, out.out, out.err
