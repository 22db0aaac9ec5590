"""Tiny synthetic videos with known masks, for the video-path tests (rendered here, in
milliseconds: a smooth random background, sensor noise, moving coloured rectangles)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seg2pose.geometry.camera import Camera
from seg2pose.structures.masks import encode

H, W = 120, 160


def background(seed: int = 0) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    small = rng.integers(60, 140, size=(12, 16, 3)).astype(np.uint8)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)


def boxes_at(frame: int, boxes: list[dict]) -> list[tuple[int, tuple[int, int, int, int]]]:
    """(id, (x0, y0, x1, y1)) of the boxes visible in ``frame``. A box dict: id, x, y (top-left
    at frame 0), w, h, vx, vy (pixels per frame), frames (first, last)."""
    out = []
    for b in boxes:
        a, z = b.get("frames", (0, 10**9))
        if not a <= frame <= z:
            continue
        x = int(round(b["x"] + b.get("vx", 0) * frame))
        y = int(round(b["y"] + b.get("vy", 0) * frame))
        out.append((b["id"], (x, y, x + b["w"], y + b["h"])))
    return out


def render(frame: int, boxes: list[dict], bg: np.ndarray, rng: np.random.Generator,
           light: float = 0.0, gain: float = 1.0) -> np.ndarray:
    """One frame: ``light`` grey levels added to the background, the boxes painted, the whole
    frame times ``gain`` (a cloud, the camera's exposure), sensor noise."""
    img = bg.astype(np.int16) + int(light)
    for bid, (x0, y0, x1, y1) in boxes_at(frame, boxes):
        img[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = (40 + 50 * bid % 200, 200, 230)
    if gain != 1.0:
        img = np.round(img * gain).astype(np.int16)
    img = img + rng.normal(0, 2.0, img.shape).round().astype(np.int16)
    return np.clip(img, 0, 255).astype(np.uint8)


def truth_mask(frame: int, boxes: list[dict], bid: int) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    for i, (x0, y0, x1, y1) in boxes_at(frame, boxes):
        if i == bid:
            m[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = 1
    return m


def write_folder(folder: Path, n: int, boxes: list[dict], light: dict[int, float] | None = None,
                 seed: int = 0, gain: dict[int, float] | None = None) -> Path:
    """PNG frames 000000.png ... (lossless: masks are exact); ``light``: grey levels added to
    the background of some frames, ``gain``: some whole frames scaled."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    bg = background(seed)
    rng = np.random.default_rng(seed + 1)
    for f in range(n):
        cv2.imwrite(str(folder / f"{f:06d}.png"), render(f, boxes, bg, rng, (light or {}).get(f, 0.0),
                                                             (gain or {}).get(f, 1.0)))
    return folder


def write_video(path: Path, n: int, boxes: list[dict], fourcc: str = "MJPG", seed: int = 0) -> Path:
    import cv2

    bg = background(seed)
    rng = np.random.default_rng(seed + 1)
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10.0, (W, H))
    for f in range(n):
        wr.write(render(f, boxes, bg, rng))
    wr.release()
    return path


def single_threaded_opencv():
    """A fixture body: OpenCV on one thread while a test runs. Once OpenCV's worker pool has
    started, a process forked later (``s2p synth``'s workers in other tests) can hang in it."""
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(before)


# --- detector output and calibration files ----------------------------------------------------


def rle(x0, y0, w, h):
    m = np.zeros((H, W), np.uint8)
    m[y0:y0 + h, x0:x0 + w] = 1
    return {"size": [H, W], "counts": encode(m).decode()}


def det(image_id, cat, seg, score=0.9):
    return {"image_id": image_id, "category_id": cat, "segmentation": seg, "score": score}


def calibration(tmp_path, name="c0", with_size=False):
    cam = Camera.look_at(name, np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 150.0, W, H)
    d = {"name": name, "K": cam.K.tolist(), "R": cam.R.tolist(), "t": cam.t.tolist()}
    if with_size:
        d.update(width=W + 10, height=H)
    (tmp_path / "calib.json").write_text(json.dumps({"cameras": [d]}))
    g = "\n".join(f"{x},{y},0" for x in range(-20, 21, 10) for y in range(-10, 41, 10))
    (tmp_path / "ground.csv").write_text(g + "\n")
    return cam


# --- world-sized boxes ----------------------------------------------------------------------


def upright_box(cam: Camera, xy, width: float, height: float) -> tuple[int, int, int, int]:
    """Pixel box x0, y0, x1, y1 (not clipped to the image) of an upright rectangle width x
    height metres standing at ground point xy (z = 0), facing camera ``cam``."""
    F = np.array([xy[0], xy[1], 0.0])
    view = F[:2] - cam.center[:2]
    u = np.array([-view[1], view[0], 0.0]) / np.linalg.norm(view)
    corners = np.array([F - u * width / 2, F + u * width / 2,
                        F + u * width / 2 + [0, 0, height], F - u * width / 2 + [0, 0, height]])
    uv, _, _ = cam.project_points(corners)
    return (*np.floor(uv.min(axis=0)).astype(int), *np.ceil(uv.max(axis=0)).astype(int))
