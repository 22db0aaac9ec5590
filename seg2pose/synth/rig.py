"""The five-lens camera device of the paper's Figure 5, mounted on a pole at the junction.

All five lenses are parallel (one rotation) and sit in the device's front plane. Offsets in
that plane, metres, ``(h, v)`` = (to the right, up) as seen from behind the device:

    c0 (-0.20, 0)   c1 (0, 0)   c3 (0.10, 0)   c2 (0.20, 0)
                    c4 (0, -0.10)

which realises every configuration of Figure 5 with five lenses:

    mono-1 c1, mono-2 c0, mono-3 c2
    stereo-10 c1+c3 (10 cm), stereo-30 c0+c3 (30 cm), stereo-40 c0+c2 (40 cm)
    tri-I c0+c1+c2 (in a line, 20 + 20 cm)
    tri-L c4+c1+c3 (a right angle, 10 cm arms)
    tri-T c0+c2+c4 (a 40 cm bar with a lens 10 cm below its middle)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import Camera, OpenCVDistortion, Rig

WIDTH, HEIGHT = 1280, 720
FOCAL = 900.0  # pixels: about 71 x 44 degrees field of view

LENS_OFFSETS = {  # (right, up) metres in the device plane
    "c0": (-0.20, 0.0),
    "c1": (0.0, 0.0),
    "c2": (0.20, 0.0),
    "c3": (0.10, 0.0),
    "c4": (0.0, -0.10),
}
CONFIGS = {
    "mono-1": ["c1"],
    "mono-2": ["c0"],
    "mono-3": ["c2"],
    "stereo-10": ["c1", "c3"],
    "stereo-30": ["c0", "c3"],
    "stereo-40": ["c0", "c2"],
    "tri-I": ["c0", "c1", "c2"],
    "tri-L": ["c4", "c1", "c3"],
    "tri-T": ["c0", "c2", "c4"],
}
# named devices: pole position (x, y), height, look-at target, focal length
# (tilted so that the top of the image sees about 50-60 m far: beyond that, a pixel spans
# metres of ground at grazing angles and no detector-based method is meaningful)
DEVICES = {
    "device": dict(pole=(-12.0, -12.0), height=10.0, target=(-1.0, -1.0, 0.0)),
    "device-8m": dict(pole=(-12.0, -12.0), height=8.0, target=(-3.0, -3.0, 0.0)),
    "device-12m": dict(pole=(-12.0, -12.0), height=12.0, target=(1.0, 1.0, 0.0)),
}


HEIGHT_RANGE = (6.0, 15.0)  # metres: the pole heights of ``device_at``


def device_at(height: float, *, distortion: tuple[float, float] | None = None) -> Rig:
    """The five-lens device on the usual pole at ``height`` metres (HEIGHT_RANGE), tilted as
    the named devices are (the target moves 1 m along the diagonal per metre of height, so
    that the top of the image still sees about 50-60 m far). Named ``device-<h>m``."""
    if not HEIGHT_RANGE[0] <= height <= HEIGHT_RANGE[1]:
        raise InputError(f"camera height must be within {HEIGHT_RANGE[0]:g}-{HEIGHT_RANGE[1]:g} m, "
                         f"got {height}", field="camera_height")
    spec = dict(pole=(-12.0, -12.0), height=float(height), target=(height - 11.0, height - 11.0, 0.0))
    return build_device(f"device-{height:g}m", spec, distortion=distortion)


def make_device(name: str = "device", *, focal: float = FOCAL, width: int = WIDTH,
                height: int = HEIGHT, distortion: tuple[float, float] | None = None) -> Rig:
    """The five-lens device ``name`` (see DEVICES) as a Rig with the paper's configurations.

    distortion: optional (k1, k2) radial distortion for every lens (off by default)."""
    if name not in DEVICES:
        raise InputError(f"unknown rig {name!r}; known: {', '.join(DEVICES)} or a rig JSON file",
                         field="rig")
    return build_device(name, DEVICES[name], focal=focal, width=width, height=height,
                        distortion=distortion)


def build_device(name: str, spec: dict, *, focal: float = FOCAL, width: int = WIDTH,
                 height: int = HEIGHT, distortion: tuple[float, float] | None = None) -> Rig:
    """The five-lens device of ``spec`` (pole (x, y), height, look-at target; see DEVICES)."""
    centre = np.array([spec["pole"][0], spec["pole"][1], spec["height"]])
    dist = OpenCVDistortion(k1=distortion[0], k2=distortion[1]) if distortion else None
    ref = Camera.look_at("ref", centre, np.asarray(spec["target"], float), focal, width, height)
    cams = {}
    for lens, (h, v) in LENS_OFFSETS.items():
        # camera axes: x right, y down; a lens 'up' in the device is -y in camera coordinates
        c = centre + ref.R.T @ np.array([h, -v, 0.0])
        cams[lens] = Camera(name=lens, K=ref.K.copy(), R=ref.R.copy(), t=-ref.R @ c,
                            width=width, height=height, distortion=dist)
    return Rig(cameras=cams, configs={k: list(v) for k, v in CONFIGS.items()}, name=name)


def load_rig(spec: str | Path | Rig | None, distortion: tuple[float, float] | None = None) -> Rig:
    """A rig from a device name, a JSON file ({"cameras": [...], "configs": {...}} in
    scene.json's format), or a Rig (returned as is). None = the default device.
    distortion: (k1, k2) for the named devices (a JSON rig carries its own)."""
    if distortion is not None:
        if len(distortion) != 2 or not all(np.isfinite(distortion)) or abs(distortion[0]) > 1 \
                or abs(distortion[1]) > 1:
            raise InputError(f"expected k1,k2 with |k| <= 1, got {distortion}", field="distortion")
    if spec is None:
        return make_device(distortion=distortion)
    if isinstance(spec, Rig):
        return spec
    s = str(spec)
    if s in DEVICES:
        return make_device(s, distortion=distortion)
    p = Path(s)
    if p.suffix.lower() == ".json" or p.exists():
        if not p.exists():
            raise InputError("rig file not found", file=p, field="rig")
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except json.JSONDecodeError as e:
            raise InputError(f"invalid JSON: {e.msg}", file=p, line=e.lineno) from None
        if not isinstance(d, dict) or not isinstance(d.get("cameras"), list) or not d["cameras"]:
            raise InputError("expected an object with a non-empty 'cameras' list", file=p,
                             field="cameras")
        cams = {}
        for i, cd in enumerate(d["cameras"]):
            cam = Camera.from_dict(cd, file=p, where=f"cameras[{i}]")
            cams[cam.name] = cam
        try:
            return Rig(cameras=cams, configs=d.get("configs") or {}, name=str(d.get("rig", p.stem)))
        except InputError as e:
            raise InputError(str(e), file=p, field=e.field) from None
    raise InputError(f"unknown rig {s!r}; known: {', '.join(DEVICES)} or a rig JSON file",
                     field="rig")
