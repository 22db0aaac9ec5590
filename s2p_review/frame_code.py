"""A video whose frames show their own number (a "frame code"): big black and white blocks
across the top fifth of the image, readable after video compression, scaling and a
screenshot. Checks that a viewer shows frame f when it says f (tests/test_review.py,
tests/test_annotate_browser.py, benches/bench_app.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
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
