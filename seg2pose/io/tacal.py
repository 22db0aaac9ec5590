"""T-Analyst's ``.tacal`` calibration files (Tsai's camera model), read and written.

A ``.tacal`` is plain text, one ``name: value`` per line, 19 names::

    dx, dy   sensor element size (sensor units per pixel, e.g. mm)
    Cx, Cy   principal point (pixels)
    Sx       horizontal scale factor
    f        focal length (sensor units)
    k        radial distortion (1 / sensor units²), defined from the distorted point
    Tx, Ty, Tz, r1 … r9   world -> camera: [Xc, Yc, Zc] = R [x, y, z] + T, R = [[r1, r2, r3], …]

Projection: Xu = f Xc / Zc, Yu = f Yc / Zc; Xu = Xd (1 + k (Xd² + Yd²)), likewise Yu;
u = Sx Xd / dx + Cx, v = Yd / dy + Cy. As a :class:`~seg2pose.geometry.camera.Camera` that is
K = [[Sx f / dx, 0, Cx], [0, f / dy, Cy], [0, 0, 1]], R, t = T and a
:class:`~seg2pose.geometry.camera.TsaiDistortion` (k, f). The pixel coordinates (u, v) are taken to be
in s2p's convention (origin at the top-left corner of the image): the file does not say
otherwise, and Tsai's frame-buffer principal point of a 2Cx-wide image is then its centre.

A ``.tacal`` has no image size; callers give it (or take 2 Cx x 2 Cy).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.core.validate import FPS_RANGE, MAX_IMAGE_SIDE, safe_name
from seg2pose.geometry.camera import MAX_DISTORTION, Camera, OpenCVDistortion, Rig, TsaiDistortion
from seg2pose.io.atomic import atomic_write_text, outputs
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, read_ground_points
from seg2pose.io.text import read_text

TACAL_FIELDS = ("dx", "dy", "Cx", "Cy", "Sx", "f", "k", "Tx", "Ty", "Tz",
                "r1", "r2", "r3", "r4", "r5", "r6", "r7", "r8", "r9")
# a rotation written with ~6 decimals is orthonormal to ~1e-6; further off is not a rotation
R_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Tacal:
    """The 19 numbers of a ``.tacal`` file, as written there (units: see the module doc)."""

    dx: float
    dy: float
    Cx: float
    Cy: float
    Sx: float
    f: float
    k: float
    Tx: float
    Ty: float
    Tz: float
    r1: float
    r2: float
    r3: float
    r4: float
    r5: float
    r6: float
    r7: float
    r8: float
    r9: float

    @property
    def R(self) -> np.ndarray:
        """(3, 3) world -> camera rotation as written (not re-orthonormalised)."""
        return np.array([getattr(self, f"r{i}") for i in range(1, 10)], dtype=np.float64).reshape(3, 3)

    @property
    def T(self) -> np.ndarray:
        """(3,) translation, world units (metres)."""
        return np.array([self.Tx, self.Ty, self.Tz], dtype=np.float64)


def _number(text: str, file: Path, line: int, name: str) -> float:
    t = text.strip()
    if "," in t and "." not in t and t.count(",") == 1:
        t = t.replace(",", ".")  # a decimal comma, as Swedish-locale tools write
    try:
        v = float(t)
    except ValueError:
        raise InputError(f"expected a number for '{name}', got {text.strip()!r}", file=file,
                         line=line, field=name) from None
    if not np.isfinite(v):
        raise InputError(f"'{name}' is NaN or inf", file=file, line=line, field=name)
    return v


def parse_tacal(text: str, file: str | Path = "<tacal>") -> Tacal:
    """Parse the text of a ``.tacal``; errors name the file, the line and the field."""
    file = Path(file)
    values: dict[str, float] = {}
    where: dict[str, int] = {}
    for lineno, raw in enumerate(text.lstrip("\ufeff").splitlines(), start=1):
        if not raw.strip():
            continue
        name, sep, value = raw.partition(":")
        name = name.strip()
        if not sep:
            raise InputError(f"expected 'name: value', got {raw.strip()!r}", file=file, line=lineno)
        if name not in TACAL_FIELDS:
            raise InputError(f"unknown field {name!r}; a .tacal has {', '.join(TACAL_FIELDS)}",
                             file=file, line=lineno)
        if name in values:
            raise InputError(f"'{name}' given twice (first on line {where[name]})", file=file,
                             line=lineno, field=name)
        values[name] = _number(value, file, lineno, name)
        where[name] = lineno
    missing = [n for n in TACAL_FIELDS if n not in values]
    if missing:
        raise InputError(f"missing field(s) {', '.join(missing)}: a .tacal has 19 lines "
                         f"{', '.join(TACAL_FIELDS)}", file=file, field=missing[0])
    for name in ("dx", "dy", "f", "Sx"):
        if values[name] <= 0:
            raise InputError(f"'{name}' must be positive, got {values[name]!r}", file=file,
                             line=where[name], field=name)
    return Tacal(**values)


def read_tacal(path: str | Path) -> Tacal:
    path = Path(path)
    return parse_tacal(read_text(path, ".tacal file"), path)


def format_tacal(cal: Tacal) -> str:
    """The file text: the 19 lines in the canonical order, numbers as Python's shortest repr
    (so reading it back gives the same floats)."""
    return "".join(f"{f.name}: {float(getattr(cal, f.name))!r}\n" for f in fields(cal))


def write_tacal(path: str | Path, cal: Tacal) -> None:
    atomic_write_text(path, format_tacal(cal))


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation closest to R (Frobenius norm): the polar factor U Vᵀ of its SVD."""
    U, _, Vt = np.linalg.svd(R)
    if np.linalg.det(U @ Vt) < 0:
        U[:, -1] *= -1
    return U @ Vt


def tacal_to_camera(cal: Tacal, name: str, width: int | None = None, height: int | None = None,
                    file: str | Path | None = None) -> Camera:
    """A Camera that projects as the ``.tacal`` formulas do. R is replaced by the nearest
    rotation when it is off by less than R_TOLERANCE (files round r1…r9; the change moves
    pixels by ~f·1e-6); further off is an error. width/height default to 2 Cx x 2 Cy."""
    R = cal.R
    if np.abs(R).max() > 2:  # not a rotation, and R Rᵀ would overflow for absurd entries
        raise InputError(f"r1…r9 are not a rotation matrix (an entry is {np.abs(R).max():g})",
                         file=file, field="r1")
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > R_TOLERANCE or np.linalg.det(R) <= 0:
        raise InputError(f"r1…r9 are not a rotation matrix (R Rᵀ is off the identity by {err:.2g}"
                         f"{', det < 0' if np.linalg.det(R) <= 0 else ''})", file=file, field="r1")
    # the limits scene.json's reader applies: a camera it would refuse is refused here
    for key in ("k", "f"):
        v = getattr(cal, key)
        if not abs(v) <= MAX_DISTORTION:
            raise InputError(f"'{key}' must be within +-{MAX_DISTORTION:g} (what a scene holds), "
                             f"got {v!r}", file=file, field=key)
    with np.errstate(all="ignore"):
        K = np.array([[cal.Sx * cal.f / cal.dx, 0.0, cal.Cx], [0.0, cal.f / cal.dy, cal.Cy],
                      [0.0, 0.0, 1.0]])
    if not abs(2 * cal.Cx) < 2 * MAX_IMAGE_SIDE or not abs(2 * cal.Cy) < 2 * MAX_IMAGE_SIDE:
        raise InputError(f"Cx, Cy = {cal.Cx:g}, {cal.Cy:g} put the image centre more than "
                         f"{MAX_IMAGE_SIDE} pixels out", file=file, field="Cx")
    w = int(round(2 * cal.Cx)) if width is None else int(width)
    h = int(round(2 * cal.Cy)) if height is None else int(height)
    if w <= 0 or h <= 0:
        raise InputError(f"cannot take the image size from Cx, Cy = {cal.Cx}, {cal.Cy}; give it",
                         file=file, field="Cx")
    if w > MAX_IMAGE_SIDE or h > MAX_IMAGE_SIDE:
        raise InputError(f"image size {w}x{h} is more than {MAX_IMAGE_SIDE} pixels a side",
                         file=file, field="size")
    fields_of = {"K": "f", "R": "r1", "t": "Tx"}
    try:
        cam = Camera(name=name, K=K, R=nearest_rotation(R), t=cal.T, width=w, height=h,
                     distortion=TsaiDistortion(k=cal.k, f=cal.f))
        Camera.from_dict(cam.to_dict(), file=file)  # exactly as a scene.json is read
    except InputError as e:
        field = fields_of.get(e.field or "", e.field)
        if field and "." in field:  # the reader's name: cameras[c0].K -> the .tacal's
            field = fields_of.get(field.rsplit(".", 1)[-1], field)
        raise InputError(e.message, file=file, field=field) from None
    return cam


def camera_to_tacal(cam: Camera) -> Tacal:
    """The ``.tacal`` numbers of a camera without skew and with no or Tsai distortion.
    f comes from the Tsai distortion when there is one, otherwise the sensor unit is the pixel
    height (dy = 1, f = fy); dx = dy and Sx = fx / fy. A camera read from a ``.tacal`` with
    dx = dy therefore gives its numbers back (up to rounding in the last digit)."""
    K = cam.K
    if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]) or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0:
        raise InputError(f"camera {cam.name!r} has a skewed K; Tsai's model has no skew",
                         field=f"cameras[{cam.name}].K")
    d = cam.distortion
    if isinstance(d, TsaiDistortion):
        f, k = d.f, d.k
    elif d is None or (isinstance(d, OpenCVDistortion) and d.is_identity):
        f, k = float(K[1, 1]), 0.0
    else:
        raise InputError(f"camera {cam.name!r} has {d.model!r} lens distortion, which a .tacal "
                         "cannot hold (only Tsai's radial k)", field=f"cameras[{cam.name}].distortion")
    dy = f / K[1, 1]
    R, T = cam.R, cam.t
    return Tacal(dx=dy, dy=dy, Cx=float(K[0, 2]), Cy=float(K[1, 2]), Sx=float(K[0, 0] / K[1, 1]),
                 f=f, k=k, Tx=float(T[0]), Ty=float(T[1]), Tz=float(T[2]),
                 **{f"r{i + 1}": float(v) for i, v in enumerate(R.ravel())})


def scene_from_tacals(files: Sequence[str | Path], ground_points: str | Path, out: str | Path,
                      fps: float, size: tuple[int, int] | None = None, force: bool = False):
    """A new scene folder ``out`` from ``.tacal`` files (camera names from the file names'
    stems), a ground points CSV and the video's frame rate. Configurations: one per camera
    (named as the camera) and ``all``. size: (width, height) pixels of every camera; default
    2 Cx x 2 Cy of each file. The folder is built beside ``out`` and swapped in whole (with
    ``force`` nothing of an old one is kept). Returns the saved Scene."""
    out = Path(out)
    if not files:
        raise InputError("no .tacal files given")
    if not (np.isfinite(fps) and FPS_RANGE[0] <= fps <= FPS_RANGE[1]):
        raise InputError(f"the frame rate must be a number in [{FPS_RANGE[0]:g}, "
                         f"{FPS_RANGE[1]:g}], got {fps!r}", field="fps")
    with outputs([out], force) as built:
        cameras: dict[str, Camera] = {}
        sources: dict[str, str] = {}
        for path in map(Path, files):
            name = safe_name(path.stem, file=path, what="camera name (from the file name)")
            if name == "all":
                raise InputError("a camera cannot be named 'all' (the configuration of every "
                                 "camera); rename the file", file=path)
            if name in cameras:
                raise InputError(f"two files give camera {name!r} ({sources[name]} and {path}); "
                                 "camera names come from the file names", file=path)
            w, h = size if size is not None else (None, None)
            cameras[name] = tacal_to_camera(read_tacal(path), name, w, h, file=path)
            sources[name] = str(path.resolve())
        pts = read_ground_points(ground_points)
        configs = {n: [n] for n in cameras}
        configs["all"] = list(cameras)
        scene = Scene(root=out, name=out.name, fps=float(fps), rig=Rig(cameras, configs, name="tacal"),
                      ground_points=pts, classes=[ClassSpec(**c) for c in DEFAULT_CLASSES],
                      extra={"imported_from": {"tacal": sources,
                                               "ground_points": str(Path(ground_points).resolve())}})
        scene.check()  # as load_scene reads it, naming OUT's files
        scene.save(built.folder(out))
    return scene
