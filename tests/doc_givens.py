"""The reader's own files that the docs' commands start from (tests/system/test_doc_commands.py):
what a researcher brings -- a video of their junction, an aerial image with its world file,
surveyed pairs, a calibration file, a detector's COCO output, T-Analyst files, a UTOCS
recording -- made here from one small synthetic junction with video, and the reader's hands on
the pages the docs open (clicks on the calibration page, keyframes in the annotation app).

Every file name here is one the docs use; nothing here replaces a documented command."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

CAMS = ("c0", "c1", "c2")  # the junction's cameras in the docs (the five-lens device's first three)
FRAMES = 20  # frames per split: about 70 frames of video at 13.3 fps, enough to learn the road


def make_givens(root: Path) -> Path:
    """Write the reader's files into ``root`` (returned)."""
    import cv2

    from seg2pose.geometry.camera import Rig
    from seg2pose.io.atomic import atomic_write_bytes, atomic_write_text
    from seg2pose.io.calib_files import world_to_aerial, write_world_file
    from seg2pose.io.scene import load_scene
    from seg2pose.synth.aerial import render_aerial
    from seg2pose.synth.clicks import spread_clicks
    from seg2pose.synth.generate import SynthOptions, generate_scene
    from seg2pose.synth.rig import make_device

    dev = make_device()
    rig = Rig(cameras={c: dev.cameras[c] for c in CAMS}, configs={"tri-I": list(CAMS)}, name="device")
    site = root / ".site"
    generate_scene(site, SynthOptions(preset="small", frames=FRAMES, seed=3, rig=rig, video=True,
                                      progress=False, workers=1))
    scene = load_scene(site)
    # videos: the junction seen by one camera (street.mp4) or by three (c0-c2.mp4)
    for c in CAMS:
        shutil.copy(site / "video" / f"{c}.mp4", root / f"{c}.mp4")
    shutil.copy(site / "video" / "c0.mp4", root / "street.mp4")
    shutil.copy(site / "video" / "c1.mp4", root / "street1.mp4")
    # a calibration file and ground points (what a survey or an earlier calibration gives)
    atomic_write_text(root / "calib.json", json.dumps(
        {"cameras": [scene.cameras[c].to_dict() for c in CAMS]}, indent=1))
    shutil.copy(site / "ground_points.csv", root / "ground.csv")
    # the aerial image with its world file, and pairs clicked on frame and aerial image
    aerial, A = render_aerial((-30.0, -30.0), (40.0, 40.0), 0.1)
    atomic_write_bytes(root / "ortho.png", cv2.imencode(".png", aerial)[1].tobytes())
    write_world_file(root / "ortho.pgw", A)
    uv, X = spread_clicks(scene.cameras["c0"], 8, np.random.default_rng(11))
    ax = world_to_aerial(A, X[:, :2])
    clicks = [{"camera": "c0", "u": float(u), "v": float(v), "ax": float(a), "ay": float(b)}
              for (u, v), (a, b) in zip(uv, ax, strict=True)]
    clicks[0]["z"] = float(X[0, 2])  # one elevation typed in, as the guide suggests
    atomic_write_text(root / ".clicks.json", json.dumps(clicks))
    rows = ["camera,u,v,x,y,z,name"] + [f"c0,{u:.2f},{v:.2f},{x:.3f},{y:.3f},{z:.3f},p{i}"
                                        for i, ((u, v), (x, y, z)) in enumerate(zip(uv, X, strict=True))]
    atomic_write_text(root / "pairs.csv", "\n".join(rows) + "\n")
    atomic_write_text(root / "four-pairs.csv", "\n".join(rows[:5]) + "\n")
    _detections(site, root)
    _tanalyst(site, root)
    _utocs(root / "SRC")
    return root


def _detections(site: Path, root: Path) -> None:
    """A detector's COCO results per camera (dets_c0.json, dets_c1.json): the synthetic masks
    as a Mask R-CNN would report them (COCO categories person 1, bicycle 2, car 3)."""
    from seg2pose.io.atomic import atomic_write_text
    from seg2pose.io.mots import read_mots

    coco = {"pedestrian": [1], "bicyclist": [1, 2], "car": [3]}
    names = {c["id"]: c["name"] for c in json.loads((site / "scene.json").read_text())["classes"]}
    for cam in ("c0", "c1"):
        dets = []
        m = read_mots(site / "masks" / f"{cam}.txt")
        for f, k, rle in zip(m.frame, m.class_id, m.rles, strict=True):
            for cat in coco[names[int(k)]]:
                dets.append({"image_id": int(f), "category_id": cat, "score": 0.9,
                             "segmentation": {"size": [m.height, m.width], "counts": rle.decode()}})
        atomic_write_text(root / f"dets_{cam}.json", json.dumps(dets))


def _tanalyst(site: Path, root: Path) -> None:
    """T-Analyst files: two .tacal calibrations (north, south) and a tracks CSV (tracks.csv)."""
    from seg2pose.io.poses import read_poses
    from seg2pose.io.scene import load_scene
    from seg2pose.io.tacal import camera_to_tacal, write_tacal
    from seg2pose.io.tanalyst import TAnalystTable, write_tanalyst

    scene = load_scene(site)
    write_tacal(root / "north.tacal", camera_to_tacal(scene.cameras["c0"]))
    write_tacal(root / "south.tacal", camera_to_tacal(scene.cameras["c2"]))
    gt = read_poses(site / "gt" / "poses.csv")
    keep = gt.frame % 5 == 0  # a detection every fifth frame, as T-Analyst users place them
    kinds = {"car": "Car", "pedestrian": "Pedestrian", "bicyclist": "Bicyclist"}
    t0 = 7 * 3600_000 + 30 * 60_000  # 07:30:00.000, the time of frame 0
    ms = np.rint(t0 + gt.frame[keep] * 1000.0 / 15.0).astype(np.int64)  # a 15 fps recording
    table = TAnalystTable(detection_id=np.arange(1, keep.sum() + 1),
                          road_user_type=[kinds[c] for c in np.asarray(gt.cls)[keep]],
                          road_user_id=gt.track_id[keep], xy=gt.xyz[keep, :2],
                          time_ms=ms)
    write_tanalyst(root / "tracks.csv", table)


def _utocs(src: Path) -> None:
    """A UTOCS (CARLA) recording: two cameras, three frames, three road users."""
    from seg2pose.io.atomic import atomic_write_text

    cams = [{"id": 0, "x": -12.0, "y": 3.0, "z": 6.0, "pitch": -25.0, "roll": 0.0, "yaw": 20.0},
            {"id": 1, "x": 10.0, "y": -8.0, "z": 5.0, "pitch": -20.0, "roll": 3.0, "yaw": 140.0}]
    users = [{"type": "car", "id": 7, "x": 1.0, "y": 2.0, "z": 0.1, "l": 4.5, "w": 1.8, "h": 1.5,
              "forward_x": 0.6, "forward_y": 0.8},
             {"type": "Pedestrian", "id": 9, "x": -2.0, "y": 4.0, "z": 0.0, "l": 0.5, "w": 0.5,
              "h": 1.8, "forward_x": -1.0, "forward_y": 0.0}]
    atomic_write_text(src / "cameras.json", json.dumps(
        {"instrinsics": {"f": 400.0, "Cx": 160.0, "Cy": 120.0}, "cams": cams}))
    g = [(x, y, 0.0) for x in range(-10, 11, 5) for y in range(-10, 11, 5)]
    atomic_write_text(src / "ground_points.txt", "\n".join(f"{x},{y},{z}" for x, y, z in g) + "\n")
    for frame in range(3):
        atomic_write_text(src / "positions" / f"{frame:06d}.json",
                          json.dumps([dict(u, x=u["x"] + 0.5 * frame) for u in users]))


def click_calibration_page(url: str, cwd: Path) -> None:
    """The reader on the calibration page: eight pairs (one with its elevation), Solve, Save."""
    clicks = json.loads((cwd / ".clicks.json").read_text())
    for c in clicks:
        _post(url, "/api/pair", c)
    _post(url, "/api/solve", {})
    _post(url, "/api/save", {})


def _post(url: str, path: str, body: dict) -> dict:
    import urllib.request

    base, _, query = url.partition("/?")
    token = query.split("=", 1)[1]
    req = urllib.request.Request(base + path, data=json.dumps(body).encode(), method="POST",
                                 headers={"Authorization": f"Bearer {token}",
                                          "Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=120) as r:
        return json.loads(r.read())


def place_keyframes(scene: Path, run: Path | None, n_tracks: int = 3, every: int = 8) -> int:
    """The reader in the annotation app: a track for each of ``n_tracks`` road users of the run
    (else of the truth), keyframes every ``every`` frames where it is (clicks on it). The
    number of keyframes placed."""
    from annotate import Project
    from seg2pose.io.poses import read_poses

    if run is None and not (scene / "gt" / "poses.csv").is_file():
        return 0  # nothing to click on: the reader looks at what is there (imported tracks)
    poses = read_poses(run / "poses.csv") if run is not None else read_poses(scene / "gt" / "poses.csv")
    ids, counts = np.unique(poses.track_id, return_counts=True)
    placed = 0
    with Project.open(scene) as p:
        for tid in ids[np.argsort(-counts)][:n_tracks]:
            rows = np.flatnonzero(poses.track_id == tid)[::every]
            t = p.create_track(str(poses.cls[rows[0]]))
            for r in rows:
                p.set_keyframe(t.track, int(poses.frame[r]), x=float(poses.xyz[r, 0]),
                               y=float(poses.xyz[r, 1]))
                placed += 1
    return placed
