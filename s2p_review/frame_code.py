"""A video whose frames show their own number (a "frame code"): big black and white blocks
across the top fifth of the image, readable after video compression, scaling and a
screenshot. Checks that a viewer shows frame f when it says f (tests/test_review.py,
tests/test_annotate_browser.py, benches/bench_app.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seg2pose.io.atomic import atomic_path

CODE_BITS = 10  # frames 0..1023


def code_image(frame: int, width: int, height: int) -> np.ndarray:
    """A BGR image (height, width, 3) that shows its frame number as CODE_BITS big blocks
    across the top fifth (white = 1, most significant first) over a grey rest: readable after
    video compression and scaling (``read_code``), and above where road users usually are."""
    img = np.full((height, width, 3), 90, np.uint8)
    bw = width // CODE_BITS
    for b in range(CODE_BITS):
        on = (frame >> (CODE_BITS - 1 - b)) & 1
        img[: height // 5, b * bw:(b + 1) * bw] = 255 if on else 0
    return img


def read_code(sample) -> int:
    """The frame number of a ``code_image``: ``sample(u, v)`` gives the grey level at the
    image position (u, v), fractions of the image's width and height."""
    return sum(int(sample(u, v) > 128) << (CODE_BITS - 1 - b) for b, (u, v) in enumerate(
        code_centres()))


def code_centres(width: int = 1, height: int = 1) -> list[tuple[float, float]]:
    """Image positions of the code blocks' centres (fractions of the image if width = height = 1)."""
    return [((b + 0.5) / CODE_BITS * width, 0.1 * height) for b in range(CODE_BITS)]


def write_code_video(path: Path, width: int, height: int, frames: int, fps: float = 10.0,
                     texture: bool = False) -> None:
    """An MP4 whose frame f is ``code_image(f)``; ``texture``: over a fixed random texture with
    a few moving blocks (a static camera's scene compresses like this), not flat grey."""
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    base = None
    if texture:
        base = cv2.GaussianBlur(rng.integers(0, 256, (height, width, 3), dtype=np.uint8), (0, 0), 2)
    with atomic_path(path) as tmp:
        _write_mp4v(tmp, base, width, height, frames, fps)


def _write_mp4v(path: Path, base, width: int, height: int, frames: int, fps: float) -> None:
    import cv2

    vw = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, (width, height))
    for f in range(frames):
        img = code_image(f, width, height)
        if base is not None:
            band = height // 5
            img[band:] = base[band:]
            for k in range(4):  # road users crossing
                x = int((f * (6 + 3 * k) + 300 * k) % width)
                y = band + 40 + k * (height - band) // 5
                img[y:y + 60, x:x + 120] = (40 + 50 * k, 200 - 40 * k, 120)
        vw.write(img)
    vw.release()


def write_code_video_h264(path: Path, width: int, height: int, frames: int, bframes: int = 3,
                          gop: int = 25, vfr: bool = True, seed: int = 7) -> np.ndarray:
    """An H.264 MP4 (libx264 through PyAV) whose frame f is ``code_image(f)`` with a changing
    lower part, stored with ``bframes`` B-frames between references (out of display order) and
    a keyframe every ``gop`` frames; ``vfr``: timestamps 1/60 s to 1/15 s apart at random (a
    variable frame rate), else 1/30 s. Returns the frames' presentation timestamps (1/90000 s):
    what a phone or a surveillance camera records, and where a seek by frame count goes wrong."""
    from fractions import Fraction

    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    tb = Fraction(1, 90000)
    steps = rng.choice([1500, 3000, 3003, 4500, 6000], frames) if vfr else np.full(frames, 3000)
    pts = np.cumsum(steps)
    with atomic_path(path) as tmp, av.open(str(tmp), "w", format="mp4") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = width, height, "yuv420p"
        s.time_base = s.codec_context.time_base = tb
        s.codec_context.max_b_frames = bframes
        # b-adapt=0: B-frames where asked, not where x264's look-ahead finds them worth it
        s.options = {"preset": "veryfast", "x264-params":
                     f"bframes={bframes}:b-adapt=0:keyint={gop}:min-keyint={gop}:scenecut=0"}
        for f in range(frames):
            img = code_image(f, width, height)
            img[height // 5:, :] = 60 + (f * 7) % 120      # the rest changes too: real P/B work
            vf = av.VideoFrame.from_ndarray(img, format="bgr24")
            vf.pts, vf.time_base = int(pts[f]), tb
            c.mux(s.encode(vf))
        c.mux(s.encode())
    return pts
