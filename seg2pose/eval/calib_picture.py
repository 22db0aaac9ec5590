"""The picture of what a calibration's error costs: the camera's frame coloured by how far one
pixel of error moves a normal position there (metres per pixel, log colour scale from
``LO`` to ``HI``), hatched where the calibration extrapolates (outside the pairs' hull), with
the pairs (green kept, red left out, each with its error in pixels), and the suggested next
point (a yellow ring). A PNG, made without a GPU (OpenCV drawing).
"""

from __future__ import annotations

import numpy as np

from seg2pose.geometry.calib_site import CameraReport

LO, HI = 0.005, 0.5  # metres per pixel at the ends of the colour scale


def cost_picture(rep: CameraReport, frame: np.ndarray | None = None) -> bytes:
    """PNG bytes of the picture; ``frame`` (H, W, 3) BGR uint8, or None for a grey ground."""
    import cv2

    cam = rep.solution.camera
    w, h = cam.width, cam.height
    base = np.full((h, w, 3), 90, np.uint8) if frame is None else np.ascontiguousarray(frame[:h, :w])
    m = rep.maps
    val = np.clip((np.log(np.nan_to_num(m.m_per_px, nan=HI)) - np.log(LO)) / np.log(HI / LO), 0, 1)
    col = cv2.applyColorMap((val * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    col = cv2.resize(col, (w, h), interpolation=cv2.INTER_LINEAR)
    road = cv2.resize(m.road.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    ext = cv2.resize(m.extrapolating.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    out = base.copy()
    out[road] = (0.45 * base[road] + 0.55 * col[road]).astype(np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    hatch = ext & (((xx + yy) // 6) % 4 == 0)
    out[hatch] = (0.4 * out[hatch]).astype(np.uint8)
    s = rep.solution
    for i, (uv, used) in enumerate(zip(s.pairs.uv, s.used, strict=True)):
        p = (int(round(uv[0])), int(round(uv[1])))
        colour = (60, 220, 60) if used else (40, 40, 240)
        cv2.circle(out, p, 6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.circle(out, p, 6, colour, 2, cv2.LINE_AA)
        end = (int(round(uv[0] + 10 * s.residual_px[i, 0])), int(round(uv[1] + 10 * s.residual_px[i, 1])))
        cv2.line(out, p, end, colour, 1, cv2.LINE_AA)
        _text(out, f"{s.pairs.names[i]} {np.linalg.norm(s.residual_px[i]):.1f}px", (p[0] + 9, p[1] - 8))
    if rep.suggestion is not None:
        q = (int(rep.suggestion[0][0]), int(rep.suggestion[0][1]))
        cv2.circle(out, q, 14, (0, 230, 255), 3, cv2.LINE_AA)
        _text(out, "next point", (q[0] + 17, q[1] + 5))
    # the legend: the colour scale with its ends
    bw = max(10, min(200, w - 20))
    bar = cv2.applyColorMap(np.linspace(0, 255, bw).astype(np.uint8)[None, :].repeat(12, 0),
                            cv2.COLORMAP_TURBO)
    y0 = max(h - 40, 0)
    out[y0:y0 + 12, 10:10 + bw] = bar[:max(0, min(12, h - y0)), :max(0, w - 10)]
    _text(out, f"metres per pixel at 0.9 m: {LO:g} .. {HI:g} (log); hatched: extrapolating; "
               "lines: residual x10", (10, y0 - 6))
    ok, png = cv2.imencode(".png", out)
    return png.tobytes()


def _text(img: np.ndarray, s: str, org: tuple[int, int]) -> None:
    import cv2

    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
