"""Foxglove messages (the ``foxglove_schemas_protobuf`` well-known schemas) of a scene and its
road users: pure builders, one per message kind; ``mcap_export`` decides when each is written.
Frames of reference: ``world`` (the scene's, z up) and one per camera (its optical frame: x
right, y down, z forward).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from s2p_review import columns as C
from s2p_review import layout as L
from seg2pose.core.errors import InputError
from seg2pose.geometry.camera import OpenCVDistortion
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene


def timestamp(ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    t = Timestamp()
    t.FromNanoseconds(int(ns))
    return t


def color(rgb, a: float = 1.0):
    from foxglove_schemas_protobuf.Color_pb2 import Color

    return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=a)


def quat_from_matrix(M: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (3, 3)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(M).as_quat()
    return float(x), float(y), float(z), float(w)


def class_rgb(scene: Scene) -> dict[str, tuple[int, int, int]]:
    return {c.name: L.class_color(c.name, c.id) for c in scene.classes}


PLUMB_BOB_TOLERANCE_PX = 0.5  # the largest pixel error a plumb-bob stand-in may make anywhere
FIT_GRID = 81                 # pixels sampled per image side for the fit and its error


@dataclass(frozen=True)
class PlumbBobFit:
    """Foxglove's distortion (ROS plumb_bob: D = k1, k2, p1, p2, k3) for a camera, and how far
    it lands from the camera's own model over the image: max_px and mean_px pixels (0 where
    the camera's model is OpenCV's, written as it is)."""

    D: tuple[float, float, float, float, float]
    max_px: float
    mean_px: float
    fitted: bool


def fit_plumb_bob(cam) -> PlumbBobFit:
    """The plumb-bob distortion of ``cam`` (a ``geometry.camera.Camera``).

    OpenCV's model is plumb-bob itself. Another model (Tsai's, from T-Analyst's .tacal files,
    radial: x_u = x_d (1 + kappa |x_d|^2)) is fitted: pixels over the whole image (a
    FIT_GRID x FIT_GRID grid, borders included) are undistorted with the camera's model, and
    k1, k2, k3 (p1 = p2 = 0: the model is radial) minimise, by linear least squares,
    |x_d| - |x_u| (1 + k1 r^2 + k2 r^4 + k3 r^6), r = |x_u|, on normalised coordinates. The
    error is then measured in pixels: where the fitted model sends each undistorted point,
    against the pixel it came from (Brown-Conrady's polynomial, Brown 1966, of which plumb-bob
    is the first terms; Tsai 1987 for the one-term model)."""
    d = cam.distortion
    if d is None:
        return PlumbBobFit((0.0, 0.0, 0.0, 0.0, 0.0), 0.0, 0.0, False)
    if isinstance(d, OpenCVDistortion):
        return PlumbBobFit((d.k1, d.k2, d.p1, d.p2, d.k3), 0.0, 0.0, False)
    u, v = np.meshgrid(np.linspace(0.0, cam.width, FIT_GRID), np.linspace(0.0, cam.height, FIT_GRID))
    uv = np.c_[u.ravel(), v.ravel()]
    Kinv = np.linalg.inv(cam.K[:2, :2])
    xd = (uv - cam.K[:2, 2]) @ Kinv.T
    xu = d.undistort(xd)
    r2 = np.einsum("nk,nk->n", xu, xu)
    r = np.sqrt(r2)
    A = r[:, None] * np.stack([r2, r2 ** 2, r2 ** 3], axis=1)
    b = np.linalg.norm(xd, axis=1) - r
    scale = np.maximum(np.abs(A).max(axis=0), 1e-300)  # columns of one size: a stable solve
    k = np.linalg.lstsq(A / scale, b, rcond=None)[0] / scale
    D = (float(k[0]), float(k[1]), 0.0, 0.0, float(k[2]))
    back = OpenCVDistortion(k1=D[0], k2=D[1], k3=D[4]).distort(xu)
    err = np.linalg.norm((back - xd) @ cam.K[:2, :2].T, axis=1)
    if not np.isfinite(err).all():
        return PlumbBobFit(D, float("inf"), float("inf"), True)
    return PlumbBobFit(D, float(err.max()), float(err.mean()), True)


def plumb_bob(cam, tolerance_px: float = PLUMB_BOB_TOLERANCE_PX) -> PlumbBobFit:
    """``fit_plumb_bob``, refused with one line when its error exceeds ``tolerance_px``
    anywhere in the image (Foxglove would draw the annotations that far off)."""
    fit = fit_plumb_bob(cam)
    if fit.max_px > tolerance_px:
        d = cam.distortion.to_dict() if cam.distortion is not None else {}
        raise InputError(f"camera {cam.name!r}: its {d.get('model', '?')} distortion {d} cannot be "
                         f"written as Foxglove's plumb_bob within {tolerance_px:g} px (the best "
                         f"fit is off by up to {fit.max_px:.2f} px, {fit.mean_px:.2f} px on "
                         "average, over the image)", field=f"cameras[{cam.name}].distortion")
    return fit


def camera_calibration(scene: Scene, name: str, ns: int, scale: float = 1.0):
    """CameraCalibration of camera ``name`` for images ``scale`` times its size: K (first two
    rows scaled), P = [K | 0], plumb-bob distortion (``plumb_bob``: fitted for a Tsai camera,
    refused when no fit is close enough; unchanged by scaling)."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    cam = scene.cameras[name]
    D = list(plumb_bob(cam).D)
    K = np.diag([scale, scale, 1.0]) @ cam.K
    w, h = scaled_size(cam, scale)
    P = np.hstack([K, np.zeros((3, 1))])
    return CameraCalibration(timestamp=timestamp(ns), frame_id=name, width=w, height=h,
                             distortion_model="plumb_bob", D=D, K=K.ravel().tolist(),
                             R=np.eye(3).ravel().tolist(), P=P.ravel().tolist())


def scaled_size(cam, scale: float) -> tuple[int, int]:
    """(width, height) pixels of ``cam``'s images shown ``scale`` times their size."""
    return max(1, int(round(cam.width * scale))), max(1, int(round(cam.height * scale)))


def camera_transform(scene: Scene, name: str, ns: int):
    """FrameTransform world -> camera ``name`` (its centre and R^T)."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform

    cam = scene.cameras[name]
    tf = FrameTransform(timestamp=timestamp(ns), parent_frame_id="world", child_frame_id=name)
    tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in cam.center)
    tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = quat_from_matrix(cam.R.T)
    return tf


def ground(scene: Scene, ns: int):
    """SceneUpdate with the ground surface (eq. (1)) as a triangle mesh."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    verts, tris = scene.ground.mesh(n=32)
    su = SceneUpdate()
    e = su.entities.add(timestamp=timestamp(ns), frame_id="world", id="ground", frame_locked=True)
    tri = e.triangles.add()
    tri.pose.orientation.w = 1.0
    for v in verts:
        p = tri.points.add()
        p.x, p.y, p.z = (float(a) for a in v)
    tri.indices.extend(int(i) for i in tris.ravel())
    tri.color.CopyFrom(color((90, 90, 90)))
    return su


def scene_update(table: PoseTable, sizes: np.ndarray, scene: Scene, ns: int, lifetime_ns: int,
                 rgb=None, prefix: str = ""):
    """SceneUpdate with one entity per road user, id ``prefix`` + track id, metadata track_id,
    class and heading (radians, or "unknown"): a cube of its size turned by its heading, or,
    where the heading is unknown, an upright cylinder (no false heading); class colour or
    ``rgb`` for all; a label. Rows without a position are left out."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    su = SceneUpdate()
    fields = C.box_columns(table.xyz, table.heading, sizes)
    cols = L.class_colors(table.cls, scene.classes) if rgb is None else [rgb] * len(table)
    labels = L.labels(table.cls, table.track_id)
    if table.source is not None:  # annotated tracks: say which poses were placed by hand
        labels = [f"{lab} {src}" for lab, src in zip(labels, table.source)]
    for i in range(len(table)):
        if not np.isfinite(table.xyz[i]).all():
            continue
        known = bool(np.isfinite(table.heading[i]))
        e = su.entities.add(timestamp=timestamp(ns), frame_id="world",
                            id=f"{prefix}{int(table.track_id[i])}")
        e.lifetime.FromNanoseconds(lifetime_ns)
        for k, v in (("track_id", str(int(table.track_id[i]))), ("class", str(table.cls[i])),
                     ("heading", repr(float(table.heading[i])) if known else "unknown")):
            e.metadata.add(key=k, value=v)
        cx, cy, cz = (float(v) for v in fields["centers"][i])
        if known:
            prim = e.cubes.add()
            qx, qy, qz, qw = (float(v) for v in fields["quaternions"][i])
            prim.pose.orientation.x, prim.pose.orientation.y = qx, qy
            prim.pose.orientation.z, prim.pose.orientation.w = qz, qw
            prim.size.x, prim.size.y, prim.size.z = (float(v) for v in sizes[i])
        else:
            prim = e.cylinders.add(bottom_scale=1.0, top_scale=1.0)
            prim.pose.orientation.w = 1.0  # a cylinder about z looks the same any way it is turned
            d = float(max(sizes[i, 0], sizes[i, 1]))
            prim.size.x, prim.size.y, prim.size.z = d, d, float(sizes[i, 2])
        prim.pose.position.x, prim.pose.position.y, prim.pose.position.z = cx, cy, cz
        prim.color.CopyFrom(color(cols[i], 0.5 if rgb is None else 0.25))
        if rgb is None:
            t = e.texts.add(billboard=True, font_size=14.0, scale_invariant=True, text=labels[i])
            t.pose.position.x, t.pose.position.y = cx, cy
            t.pose.position.z = cz + float(sizes[i, 2]) / 2 + 0.3
            t.pose.orientation.w = 1.0
            t.color.CopyFrom(color((255, 255, 255)))
    return su


def poses_in_frame(table: PoseTable, ns: int):
    """PosesInFrame (world) of the road users with a position and a known heading (a pose
    always shows a direction, so road users of unknown heading are only in the SceneUpdate)."""
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame

    msg = PosesInFrame(timestamp=timestamp(ns), frame_id="world")
    for i in range(len(table)):
        h = float(table.heading[i])
        if not (np.isfinite(table.xyz[i]).all() and np.isfinite(h)):
            continue
        p = msg.poses.add()
        p.position.x, p.position.y, p.position.z = (float(v) for v in table.xyz[i])
        p.orientation.z, p.orientation.w = float(np.sin(h / 2)), float(np.cos(h / 2))
    return msg


def outlines(inst: np.ndarray, ids: np.ndarray, boxes: np.ndarray) -> list[np.ndarray | None]:
    """Outer contour (K, 2) pixels (pixel centres) of each id's region in an instance image
    (H, W), searched only inside the mask's bounding box (N, 4: x0, y0, x1, y1 exclusive) and
    simplified to within half a pixel; None for a mask hidden by others."""
    import cv2

    out: list = []
    for i, b in zip(ids, boxes):
        if not np.isfinite(b).all():
            out.append(None)
            continue
        x0, y0, x1, y1 = (int(v) for v in b)
        m = (inst[y0:y1, x0:x1] == i).astype(np.uint8)
        cs, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cs:
            out.append(None)
            continue
        c = cv2.approxPolyDP(max(cs, key=len), 0.5, True)[:, 0, :].astype(float)
        out.append(c + [x0 + 0.5, y0 + 0.5])
    return out


def image_annotations(camera, table: PoseTable, sizes: np.ndarray, scene: Scene, ns: int,
                      loops: Sequence[tuple[str, np.ndarray]] = (), centres: Sequence = (),
                      scale: float = 1.0):
    """Projected boxes (LINE_LIST, class colours), mask outlines ``loops`` ((class, (K, 2)
    pixels), LINE_LOOP) and the views' mask centres ``centres`` ((uv, class), POINTS) of one
    camera and frame; pixel coordinates of the camera's image, multiplied by ``scale`` (the
    size the images are shown at)."""
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

    msg = ImageAnnotations()
    segs, idx = C.projected_edges(camera, table.xyz, table.heading, sizes)
    segs = segs * scale
    cols = L.class_colors(table.cls[idx], scene.classes)
    for k in range(len(idx)):
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.LINE_LIST, thickness=2.0)
        pa.outline_color.CopyFrom(color(cols[k]))
        pa.points.extend(Point2(x=x, y=y) for x, y in segs[k * 12:(k + 1) * 12].reshape(-1, 2).tolist())
    rgb = class_rgb(scene)
    for uv, name in centres:
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.POINTS, thickness=6.0)
        pa.outline_color.CopyFrom(color(rgb.get(name, (128, 128, 128))))
        pa.points.add(x=float(uv[0]) * scale, y=float(uv[1]) * scale)
    for name, c in loops:
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.LINE_LOOP, thickness=1.0)
        pa.outline_color.CopyFrom(color(rgb.get(name, (128, 128, 128))))
        pa.points.extend(Point2(x=x, y=y) for x, y in (c * scale).tolist())
    return msg


def raw_image(img: np.ndarray, frame_id: str, ns: int):
    """RawImage of a mono16 (H, W) uint16 or rgb8 (H, W, 3) uint8 image."""
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    h, w = img.shape[:2]
    if img.ndim == 2:
        return RawImage(timestamp=timestamp(ns), frame_id=frame_id, width=w, height=h,
                        encoding="mono16", step=2 * w, data=img.astype("<u2").tobytes())
    return RawImage(timestamp=timestamp(ns), frame_id=frame_id, width=w, height=h,
                    encoding="rgb8", step=3 * w, data=np.ascontiguousarray(img, np.uint8).tobytes())


def compressed_image(jpeg: bytes, frame_id: str, ns: int):
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    return CompressedImage(timestamp=timestamp(ns), frame_id=frame_id, data=jpeg, format="jpeg")


def overlay(inst_cls: np.ndarray, rgb_of: dict[int, tuple[int, int, int]],
            video_bgr: np.ndarray | None, size: tuple[int, int] | None = None,
            alpha: float = 0.55) -> np.ndarray:
    """The display image of a mask frame, RGB (h, w, 3) uint8: each mask pixel in its class
    colour, blended over the video frame (``alpha`` of the colour) where there is one, else on
    black; shrunk to ``size`` = (w, h) when given. inst_cls: (H, W) class id per pixel (0 =
    background); rgb_of: class id -> colour."""
    import cv2

    h, w = inst_cls.shape
    if video_bgr is None:
        base = np.zeros((h, w, 3), np.uint8)
        a = 1.0
    else:
        base = np.ascontiguousarray(video_bgr[..., ::-1])
        if base.shape[:2] != (h, w):
            base = cv2.resize(base, (w, h), interpolation=cv2.INTER_LINEAR)
        a = alpha
    lut = np.zeros((max([0, *rgb_of]) + 1, 3), np.float32)
    for k, c in rgb_of.items():
        lut[k] = c
    on = inst_cls > 0
    out = base.copy()
    out[on] = np.rint((1 - a) * base[on] + a * lut[inst_cls[on]]).astype(np.uint8)
    if size is not None and size != (w, h):
        out = cv2.resize(out, size, interpolation=cv2.INTER_AREA)
    return out
