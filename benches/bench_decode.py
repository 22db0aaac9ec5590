"""Video decoding: sequential and random-seek speed and exactness of the frame-exact decoder
(seg2pose/io/video_decode.py, PyAV by presentation timestamp) against OpenCV's
``cv2.VideoCapture`` (sequential ``read``; seeks by ``CAP_PROP_POS_FRAMES``, what the readers
used before).

    .venv/bin/python benches/bench_decode.py [--frames 300] [--seeks 60] [--size 1280x720]

Two videos of ``--frames`` frames whose frames show their own number (s2p_review/frame_code.py):
mp4v (MPEG-4 part 2, no B-frames, as ``s2p synth --video`` writes) and H.264 with 3 B-frames,
a keyframe every 25 frames and a variable frame rate (as phones and many cameras record).
For each: the index (once per file), sequential decoding to BGR images of every frame, and
``--seeks`` reads at random frames (the same frames for both), with the share of wrong frames.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from s2p_review.frame_code import read_code, write_code_video, write_code_video_h264  # noqa: E402
from seg2pose.io import video_decode  # noqa: E402


def code(img: np.ndarray) -> int:
    """The frame number an image shows (7x7 patches at the code blocks' centres only)."""
    h, w = img.shape[:2]
    return read_code(lambda u, v: float(np.median(img[int(v * h) - 3:int(v * h) + 4,
                                                      int(u * w) - 3:int(u * w) + 4])))


def bench(path: Path, n: int, seeks: np.ndarray) -> dict:
    import cv2

    video_decode._INDEX_CACHE.clear()
    t = time.perf_counter()
    idx = video_decode.video_index(path)
    t_index = time.perf_counter() - t
    assert len(idx) == n, (len(idx), n)
    # sequential: every frame as a BGR image
    t = time.perf_counter()
    with video_decode.VideoDecoder(path) as dec:
        seq_ok = sum(code(im) == k for k, im in dec.frames())
    t_seq = time.perf_counter() - t
    cap = cv2.VideoCapture(str(path))
    t = time.perf_counter()
    k, cv_seq_ok = 0, 0
    while True:
        ok, im = cap.read()
        if not ok:
            break
        cv_seq_ok += code(im) == k
        k += 1
    t_cv_seq = time.perf_counter() - t
    cap.release()
    # random seeks
    t = time.perf_counter()
    with video_decode.VideoDecoder(path) as dec:
        rnd_ok = sum(code(dec.read(int(k))) == k for k in seeks)
    t_rnd = time.perf_counter() - t
    cap = cv2.VideoCapture(str(path))
    t = time.perf_counter()
    cv_rnd_ok = 0
    for k in seeks:
        cap.set(cv2.CAP_PROP_POS_FRAMES, int(k))
        ok, im = cap.read()
        cv_rnd_ok += bool(ok) and code(im) == k
    t_cv_rnd = time.perf_counter() - t
    cap.release()
    return {"index_ms": 1e3 * t_index,
            "seq_fps": n / t_seq, "seq_right": f"{seq_ok}/{n}",
            "cv2_seq_fps": n / t_cv_seq, "cv2_seq_right": f"{cv_seq_ok}/{n}",
            "seek_per_s": len(seeks) / t_rnd, "seek_right": f"{rnd_ok}/{len(seeks)}",
            "cv2_seek_per_s": len(seeks) / t_cv_rnd, "cv2_seek_right": f"{cv_rnd_ok}/{len(seeks)}"}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seeks", type=int, default=60)
    ap.add_argument("--size", default="1280x720")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    seeks = np.random.default_rng(0).integers(0, a.frames, a.seeks)
    with tempfile.TemporaryDirectory() as d:
        mp4v, h264 = Path(d) / "mp4v.mp4", Path(d) / "h264.mp4"
        write_code_video(mp4v, w, h, a.frames, fps=30.0, texture=True)
        write_code_video_h264(h264, w, h, a.frames, bframes=3, gop=25, vfr=True)
        for name, p in (("mp4v (no B-frames, constant rate)", mp4v),
                        ("H.264, 3 B-frames, GOP 25, variable rate", h264)):
            r = bench(p, a.frames, seeks)
            print(f"{name}, {w}x{h}, {a.frames} frames: index {r['index_ms']:.0f} ms")
            print(f"  sequential   PyAV by pts {r['seq_fps']:6.1f} frames/s ({r['seq_right']} right)   "
                  f"OpenCV {r['cv2_seq_fps']:6.1f} frames/s ({r['cv2_seq_right']} right)")
            print(f"  random seeks PyAV by pts {r['seek_per_s']:6.1f} reads/s ({r['seek_right']} right)   "
                  f"OpenCV POS_FRAMES {r['cv2_seek_per_s']:6.1f} reads/s ({r['cv2_seek_right']} right)")


if __name__ == "__main__":
    main()
