"""Small valid inputs of every kind, for the hostile-input, fuzzing and kill tests: each test
starts from one of these and breaks exactly one thing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.scene import ClassSpec, Scene
from seg2pose.structures.masks import encode

W, H = 64, 48
CLASSES = [ClassSpec(1, "pedestrian", 0.9), ClassSpec(2, "bicyclist", 0.9), ClassSpec(3, "car", 0.75)]


def write_scene(root: Path, frames: int = 6, users: int = 3) -> Scene:
    """A one-camera scene (c0, 64x48 px, 6 m up looking at a flat patch) with masks of
    ``users`` boxes per frame and ground truth for them."""
    cam = Camera.look_at("c0", [0.0, 0.0, 6.0], [12.0, 0.0, 0.0], 40.0, W, H)
    gx, gy = np.meshgrid(np.arange(2.0, 24.0, 4.0), np.arange(-8.0, 9.0, 4.0))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    scene = Scene(root=Path(root), name="hostile", fps=10.0,
                  rig=Rig({"c0": cam}, {"mono-1": ["c0"]}, "r"), ground_points=ground,
                  classes=list(CLASSES), splits={"train": (0, frames - 1)})
    scene.save()
    fr, tid, cid, rles, gt = [], [], [], [], []
    for f in range(frames):
        for k in range(users):
            m = np.zeros((H, W), np.uint8)
            x0 = 4 + 18 * k + f
            m[26:34, x0:x0 + 6] = 1
            fr.append(f)
            tid.append(k + 1)
            cid.append(1 + k % 3)
            rles.append(encode(m))
            gt.append((f, k + 1, CLASSES[k % 3].name, [8.0 + f * 0.1, 2.0 * k - 2, 0.0]))
    write_mots(scene.masks_path("c0"), MaskTable(fr, tid, cid, H, W, rles))
    write_poses(scene.gt_path, PoseTable([g[0] for g in gt], [g[1] for g in gt],
                                         np.array([g[2] for g in gt], object),
                                         [g[3] for g in gt], np.zeros(len(gt)),
                                         np.ones((len(gt), 3))))
    return scene


UTOCS_CAMS = [{"id": 0, "x": -12.0, "y": 3.0, "z": 6.0, "pitch": -25.0, "roll": 0.0, "yaw": 20.0}]
UTOCS_USERS = [
    {"type": "car", "id": 7, "x": 1.0, "y": 2.0, "z": 0.1, "l": 4.5, "w": 1.8, "h": 1.5,
     "forward_x": 0.6, "forward_y": 0.8},
    {"type": "pedestrian", "id": 9, "x": -2.0, "y": 4.0, "z": 0.0, "l": 0.5, "w": 0.5, "h": 1.8,
     "forward_x": -1.0, "forward_y": 0.0},
]


def write_utocs(src: Path, frames: int = 3, cams=None, users=None, images: bool = False) -> Path:
    """A tiny UTOCS recording (cameras.json, ground_points.txt, positions/NNNNNN.json)."""
    src = Path(src)
    (src / "positions").mkdir(parents=True, exist_ok=True)
    (src / "cameras.json").write_text(json.dumps(
        {"instrinsics": {"f": 200.0, "Cx": 32.0, "Cy": 24.0}, "cams": cams or UTOCS_CAMS}))
    g = [(x, y, 0.0) for x in range(-10, 11, 5) for y in range(-10, 11, 5)]
    (src / "ground_points.txt").write_text("\n".join(f"{x},{y},{z}" for x, y, z in g) + "\n")
    for f in range(frames):
        recs = [dict(u, x=u["x"] + 0.5 * f) for u in (users or UTOCS_USERS)]
        (src / "positions" / f"{f:06d}.json").write_text(json.dumps(recs))
    if images:
        import cv2

        for c in cams or UTOCS_CAMS:
            d = src / "images" / f"cam{c['id']}"
            d.mkdir(parents=True, exist_ok=True)
            for f in range(frames):
                cv2.imwrite(str(d / f"{f:06d}.png"), np.full((48, 64), 40 + f, np.uint8))
    return src


def write_s2p_mcap(path: Path, scene_d: dict, ground_name: str, poses: list | None = None,
                   run_name: str = "run") -> Path:
    """An MCAP file shaped like an `s2p export` (scene.json and ground points attachments, s2p
    metadata, /s2p/poses messages), with the given contents, for crafted-file tests."""
    from mcap.writer import Writer

    if isinstance(scene_d, dict):  # the fields not given: a valid scene's (import-mcap reads it back)
        cam = Camera.look_at("c0", [0.0, 0.0, 6.0], [12.0, 0.0, 0.0], 40.0, W, H)
        scene_d = {"fps": 10.0, "cameras": [cam.to_dict()], "configs": {"mono-1": ["c0"]}, **scene_d}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_attachment(create_time=0, log_time=0, name="scene.json", media_type="application/json",
                         data=json.dumps(scene_d).encode())
        w.add_attachment(create_time=0, log_time=0, name=ground_name, media_type="text/csv",
                         data=b"x,y,z\n0,0,0\n1,0,0\n0,1,0\n")
        w.add_metadata("s2p", {"run": run_name, "poses_with_size": "true"})
        sid = w.register_schema(name="s2p.PoseFrame", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic="/s2p/poses", message_encoding="json", schema_id=sid)
        for i, m in enumerate(poses or []):
            data = m if isinstance(m, str) else json.dumps(m)  # text: a message as given
            w.add_message(channel_id=cid, log_time=i, publish_time=i, data=data.encode())
        w.finish()
    return path


def link_test_inputs(root: Path) -> tuple[Path, Path, Path]:
    """The link tests' common inputs under ``root``: a scene of four frames (``scene``), its
    baseline run (``run``) and export (``x.mcap``), and an annotation project with one car track
    of two keyframes (``ann``): (root, the scene's folder, the project's folder)."""
    from review_fixtures import make_scene

    from annotate import Project
    from s2p_review.mcap_export import export_mcap
    from seg2pose.io.scene import load_scene
    from seg2pose.method.pipeline import RunOptions, run_scene

    scene = write_scene(root / "scene", frames=4, users=2)
    run_scene(scene, root / "run", RunOptions(baseline=True, progress=False))
    export_mcap(load_scene(scene.root), root / "run", root / "x.mcap")
    ann = make_scene(root / "ann", n_frames=10).root
    with Project.open(ann) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
        p.set_keyframe(1, 5, -4.0, -1.5, heading=0.0)
    return root, scene.root, ann

