"""Foxglove messages (the ``foxglove_schemas_protobuf`` well-known schemas) of a scene and its
road users: pure builders, one per message kind; ``mcap_export`` decides when each is written.
Frames of reference: ``world`` (the scene's, z up) and one per camera (its optical frame: x
right, y down, z forward).
"""

from __future__ import annotations

import numpy as np

from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene
from s2p_review import columns as C
from s2p_review import layout as L


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


def camera_calibration(scene: Scene, name: str, ns: int):
    """CameraCalibration of camera ``name``: K, P = [K | 0], plumb-bob distortion."""
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

    cam = scene.cameras[name]
    d = cam.distortion.to_dict() if cam.distortion is not None else {}
    D = [float(d.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")]
    P = np.hstack([cam.K, np.zeros((3, 1))])
    return CameraCalibration(timestamp=timestamp(ns), frame_id=name, width=cam.width,
                             height=cam.height, distortion_model="plumb_bob", D=D,
                             K=cam.K.ravel().tolist(), R=np.eye(3).ravel().tolist(),
                             P=P.ravel().tolist())


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
    """SceneUpdate with one entity per road user (id ``prefix`` + track id): a cube of its size
    (class colour, or ``rgb`` for all) and a label. Rows without a position are left out."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    su = SceneUpdate()
    fields = C.box_columns(table.xyz, table.heading, sizes)
    cols = L.class_colors(table.cls, scene.classes) if rgb is None else [rgb] * len(table)
    labels = L.labels(table.cls, table.track_id)
    for i in range(len(table)):
        if not np.isfinite(table.xyz[i]).all():
            continue
        e = su.entities.add(timestamp=timestamp(ns), frame_id="world",
                            id=f"{prefix}{int(table.track_id[i])}")
        e.lifetime.FromNanoseconds(lifetime_ns)
        cube = e.cubes.add()
        cx, cy, cz = (float(v) for v in fields["centers"][i])
        cube.pose.position.x, cube.pose.position.y, cube.pose.position.z = cx, cy, cz
        qx, qy, qz, qw = (float(v) for v in fields["quaternions"][i])
        cube.pose.orientation.x, cube.pose.orientation.y = qx, qy
        cube.pose.orientation.z, cube.pose.orientation.w = qz, qw
        cube.size.x, cube.size.y, cube.size.z = (float(v) for v in sizes[i])
        cube.color.CopyFrom(color(cols[i], 0.5 if rgb is None else 0.25))
        if rgb is None:
            t = e.texts.add(billboard=True, font_size=14.0, scale_invariant=True, text=labels[i])
            t.pose.position.x, t.pose.position.y = cx, cy
            t.pose.position.z = cz + float(sizes[i, 2]) / 2 + 0.3
            t.pose.orientation.w = 1.0
            t.color.CopyFrom(color((255, 255, 255)))
    return su


def poses_in_frame(table: PoseTable, ns: int):
    """PosesInFrame (world) of the road users with a position."""
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame

    msg = PosesInFrame(timestamp=timestamp(ns), frame_id="world")
    h = np.nan_to_num(table.heading)
    for i in range(len(table)):
        if not np.isfinite(table.xyz[i]).all():
            continue
        p = msg.poses.add()
        p.position.x, p.position.y, p.position.z = (float(v) for v in table.xyz[i])
        p.orientation.z, p.orientation.w = float(np.sin(h[i] / 2)), float(np.cos(h[i] / 2))
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
                      loops: list[tuple[str, np.ndarray]] = (), centres: list = ()):
    """Projected boxes (LINE_LIST, class colours), mask outlines ``loops`` ((class, (K, 2)
    pixels), LINE_LOOP) and the views' mask centres ``centres`` ((uv, class), POINTS) of one
    camera and frame."""
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation

    msg = ImageAnnotations()
    segs, idx = C.projected_edges(camera, table.xyz, table.heading, sizes)
    cols = L.class_colors(table.cls[idx], scene.classes)
    for k in range(len(idx)):
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.LINE_LIST, thickness=2.0)
        pa.outline_color.CopyFrom(color(cols[k]))
        pa.points.extend(Point2(x=x, y=y) for x, y in segs[k * 12:(k + 1) * 12].reshape(-1, 2).tolist())
    rgb = class_rgb(scene)
    for uv, name in centres:
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.POINTS, thickness=6.0)
        pa.outline_color.CopyFrom(color(rgb.get(name, (128, 128, 128))))
        pa.points.add(x=float(uv[0]), y=float(uv[1]))
    for name, c in loops:
        pa = msg.points.add(timestamp=timestamp(ns), type=PointsAnnotation.LINE_LOOP, thickness=1.0)
        pa.outline_color.CopyFrom(color(rgb.get(name, (128, 128, 128))))
        pa.points.extend(Point2(x=x, y=y) for x, y in c.tolist())
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
