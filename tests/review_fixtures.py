"""A tiny scene and run folder for the review / MCAP tests, built with the core API only (no
generator, no trained model), so these tests never depend on the heavy pipeline.

Scene: 2 cameras (160x120 px) looking at a gentle slope of 30 ground points; 3 road users (a
car, a pedestrian, a bicyclist) moving in straight lines for ``n_frames`` frames; their boxes are
projected into each camera and filled (cv2.fillConvexPoly) to make the masks. Run: the truth
shifted by a known offset, with per-view rows (mask centres, normal positions, residuals).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from s2p_review.recording import LogStyle
from s2p_review.session import RecordOptions
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.geometry.normal import normal_positions
from seg2pose.io.mots import MaskTable, write_mots
from seg2pose.io.poses import PoseTable, write_poses
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, load_scene
from seg2pose.structures.masks import encode, mask_centers

W, H = 160, 120
FPS = 10.0
SIZES = {"car": (4.5, 1.8, 1.5), "pedestrian": (0.5, 0.5, 1.7), "bicyclist": (1.8, 0.6, 1.7)}
CLASS_ID = {"pedestrian": 1, "bicyclist": 2, "car": 3}
# track id -> (class, start xy, velocity xy per frame)
TRACKS = {12: ("car", (-8.0, -1.5), (0.6, 0.0)),
          4: ("pedestrian", (2.0, 4.0), (0.0, -0.12)),
          7: ("bicyclist", (-4.0, 3.0), (0.3, 0.05))}
EST_OFFSET = np.array([0.3, -0.4, 0.0])  # the fake run = truth + this offset (metres)


def box_corners(xyz: np.ndarray, heading: np.ndarray, size: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners of boxes standing on their bottom-centre points xyz (N, 3) metres,
    rotated by heading (N,) radians, size (N, 3) l, w, h metres."""
    sx = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * 0.5
    sy = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * 0.5
    sz = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    lx = sx[None] * size[:, :1]
    ly = sy[None] * size[:, 1:2]
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    x = xyz[:, :1] + c * lx - s * ly
    y = xyz[:, 1:2] + s * lx + c * ly
    z = xyz[:, 2:3] + sz[None] * size[:, 2:3]
    return np.stack([x, y, z], axis=2)


def make_scene(root: Path, n_frames: int = 20, video: bool = False) -> Scene:
    """Write the tiny scene folder under ``root`` and return it loaded."""
    root = Path(root)
    gx, gy = np.meshgrid(np.linspace(-12, 12, 6), np.linspace(-8, 8, 5))
    pts = np.stack([gx.ravel(), gy.ravel(), 0.02 * gx.ravel()], axis=1)
    cams = {
        "c0": Camera.look_at("c0", [-14.0, -12.0, 9.0], [0.0, 0.0, 0.0], 110.0, W, H),
        "c1": Camera.look_at("c1", [14.0, -12.0, 9.0], [0.0, 0.0, 0.0], 110.0, W, H),
    }
    rig = Rig(cams, {"mono-1": ["c0"], "stereo": ["c0", "c1"]}, name="tiny")
    classes = [ClassSpec(**c) for c in DEFAULT_CLASSES]
    scene = Scene(root=root, name="tiny", fps=FPS, rig=rig, ground_points=pts, classes=classes,
                  extra={"class_sizes": {k: list(v) for k, v in SIZES.items()}})
    scene.save(root)
    gt = truth(scene, n_frames)
    (root / "gt").mkdir(exist_ok=True)
    write_poses(root / "gt" / "poses.csv", gt)
    for name, cam in cams.items():
        write_mots(scene.masks_path(name), render_masks(cam, gt))
        if video:
            write_video(root / "video" / f"{name}.mp4", cam, gt)
    return load_scene(root)


def truth(scene: Scene, n_frames: int) -> PoseTable:
    rows = []
    for f in range(n_frames):
        for tid, (cls, p0, v) in sorted(TRACKS.items()):
            xy = np.array(p0) + f * np.array(v)
            z = float(scene.ground.height(xy[None])[0])
            rows.append((f, tid, cls, xy[0], xy[1], z, float(np.arctan2(v[1], v[0])), *SIZES[cls]))
    a = np.array([r[3:] for r in rows], dtype=float)
    return PoseTable([r[0] for r in rows], [r[1] for r in rows],
                     np.array([r[2] for r in rows], dtype=object), a[:, :3], a[:, 3], a[:, 4:7])


def render_masks(cam: Camera, gt: PoseTable) -> MaskTable:
    """One filled convex hull of the projected box per road user and frame (masks in front)."""
    corners = box_corners(gt.xyz, gt.heading, gt.size)
    uv, _, front = cam.project_points(corners.reshape(-1, 3))
    uv = uv.reshape(-1, 8, 2)
    front = front.reshape(-1, 8).all(axis=1)
    keep, rles = [], []
    for i in np.flatnonzero(front):
        m = np.zeros((cam.height, cam.width), np.uint8)
        hull = cv2.convexHull(np.round(uv[i] - 0.5).astype(np.int32))
        cv2.fillConvexPoly(m, hull, 1)
        if m.any():
            keep.append(i)
            rles.append(encode(m))
    keep = np.array(keep, dtype=np.int64)
    return MaskTable(gt.frame[keep], gt.track_id[keep],
                     [CLASS_ID[c] for c in gt.cls[keep]], cam.height, cam.width, rles)


def video_rgb(frame: int) -> tuple[int, int, int]:
    """The colour of the fixture video at ``frame``."""
    return 200, 140, 60 + 4 * frame


def write_video(path: Path, cam: Camera, gt: PoseTable) -> None:
    """A flat tan video, RGB ``video_rgb(f)`` (blue grows with the frame number), one frame per gt
    frame: a colour neither the classes nor the viewer's own panels use."""
    path.parent.mkdir(parents=True, exist_ok=True)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (cam.width, cam.height))
    for f in range(int(gt.frame.max()) + 1):
        vw.write(np.full((cam.height, cam.width, 3), video_rgb(f)[::-1], np.uint8))
    vw.release()


def make_run(scene: Scene, run_dir: Path, *, method: str = "baseline", residual: float = 0.0,
             cameras: list[str] | None = None, frame_shift: int = 0) -> Path:
    """A run folder whose poses are the truth + EST_OFFSET, with views.csv rows per mask.
    ``frame_shift`` moves all frames (to make a run that does not match its scene)."""
    from seg2pose.io.mots import read_mots
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import ViewTable, relative_path, write_run_folder

    run_dir = Path(run_dir)
    gt = read_poses(scene.gt_path)
    cameras = cameras or list(scene.cameras)
    est = PoseTable(gt.frame + frame_shift, gt.track_id, gt.cls, gt.xyz + EST_OFFSET, gt.heading,
                    gt.size)
    views = []
    by_id = {c.id: c for c in scene.classes}
    for cam_name in cameras:
        if cam_name not in scene.cameras:
            views.append(ViewTable([0], [12], [cam_name], ["car"], [[1.0, 1.0]], [[0.0, 0.0, 0.0]],
                                   [[0.0, 0.0]]))
            continue
        cam = scene.cameras[cam_name]
        mt = read_mots(scene.masks_path(cam_name))
        uv = mask_centers(mt.rles, mt.height, mt.width)
        hts = np.array([by_id[c].default_height for c in mt.class_id])
        xn, _ = normal_positions(cam, scene.ground, uv, hts)
        views.append(ViewTable(mt.frame + frame_shift, mt.track_id, [cam_name] * len(mt),
                               [by_id[int(c)].name for c in mt.class_id], uv, xn,
                               np.tile([residual, -residual], (len(mt), 1))))
    meta = {"scene": relative_path(scene.root, run_dir), "scene_fingerprint": scene.fingerprint(), "config": None,
            "cameras": cameras, "method": method, "center_method": "bbox", "models": {},
            "created": "2026-01-01T00:00:00Z"}
    write_run_folder(run_dir, est, ViewTable.concat(views), meta, force=True)
    return run_dir


# --- the review tests' scene ----------------------------------------------------------------------

N_FRAMES = 20
NO_IMAGES = RecordOptions(style=LogStyle(masks=False, video=False))


def review_scene(tmp_path_factory):
    """The review tests' scene (``N_FRAMES`` frames with video) and two runs of it, baseline and
    Seg2PoseNet: (scene, base run folder, s2pn run folder, root)."""
    root = tmp_path_factory.mktemp("review")
    scene = make_scene(root / "scene", n_frames=N_FRAMES, video=True)
    base = make_run(scene, root / "scene" / "out" / "run-base")
    s2pn = make_run(scene, root / "scene" / "out" / "run-s2pn", method="seg2posenet", residual=0.2)
    return scene, base, s2pn, root


def rrd_rows(path: Path) -> tuple[Counter, Counter, list]:
    """(rows per entity, chunks per (entity, component), blueprints) of an .rrd file."""
    import rerun.chunk as rc

    reader = rc.RrdReader(path)
    rows, comps = Counter(), Counter()
    for ch in reader.stream():
        if ch.is_static:
            for n in ch.to_record_batch().schema.names:
                comps[(ch.entity_path, n)] += 1
            continue
        rows[ch.entity_path] += ch.num_rows
        for n in ch.to_record_batch().schema.names:
            comps[(ch.entity_path, n)] += 1
    return rows, comps, reader.blueprints()
