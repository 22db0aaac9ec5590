"""An annotated MCAP set: a scene with its annotated tracks in place of a run's road users (each
pose says where it came from: the ``source`` column in the lossless /s2p/poses records and in
the Foxglove labels), the annotation journal as attachments named ``annotations/<file>``, and
what a colleague needs to go on annotating from the set alone:

- every frame's video per camera as H.264 on ``/cameras/<cam>/video`` (Foxglove's
  ``CompressedVideo`` schema: Annex B access units, a keyframe with its parameter sets every
  ``GOP`` frames, no B-frames, so that Foxglove plays it);
- the scene's masks files, byte for byte, as attachments ``scene-files/masks/<cam>.txt``.

``mcap_import`` writes them back into the restored scene folder (``restore_scene_files``,
``restore_video``: ``video/<cam>.mp4`` holding the same H.264 stream, remuxed, with
``scene.json`` naming it and its first frame), where the annotation project opens again with
its tracks, undo history and pictures.

The journal is passed in as bytes (the command layer reads it with ``annotate``): review code
does not depend on the annotation engine.
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

from s2p_review import imagery
from s2p_review.mcap_export import ExportOptions, ExportResult, export_mcap
from seg2pose.core.errors import InputError, S2PError
from seg2pose.core.validate import safe_name
from seg2pose.io.atomic import atomic_write_bytes
from seg2pose.io.scene import Scene

PREFIX = "annotations/"
SCENE_FILES = "scene-files/"
VIDEO_TOPIC = re.compile(r"^/cameras/([^/]+)/video$")
GOP = 12     # frames between keyframes (as the viewer's video asset)
CRF = 23     # x264 quality: the set is for annotating on, a little better than the viewer's


def _file_name(attachment: str, file: str | Path | None = None) -> str | None:
    """The file name inside ``annotations/`` of an attachment name, or None if it is not one;
    a name that is not a plain file name (folders, '..', a leading dot) is an error."""
    if not attachment.startswith(PREFIX):
        return None
    return safe_name(attachment[len(PREFIX):], file=file, field=f"attachment {attachment}",
                     what="journal file name")


def scene_file_attachments(scene: Scene, cameras: list[str]) -> dict[str, bytes]:
    """The masks files of ``cameras`` as attachments ``scene-files/masks/<cam>.txt``."""
    out = {}
    for cam in cameras:
        path = scene.masks_path(cam)
        if path.exists():
            out[f"{SCENE_FILES}masks/{path.name}"] = path.read_bytes()
    return out


def _encoder(width: int, height: int, fps: float):
    try:
        import av
    except ImportError:
        raise S2PError("PyAV is not installed (pip install av): it encodes the set's video") from None
    cc = av.CodecContext.create("libx264", "w")
    cc.width, cc.height, cc.pix_fmt = width, height, "yuv420p"
    rate = Fraction(fps).limit_denominator(1001)
    cc.framerate, cc.time_base = rate, 1 / rate
    cc.gop_size = GOP
    # zerolatency: no B-frames and one packet per frame at once; repeat-headers: SPS/PPS with
    # every keyframe, so that a player can start at any of them (Foxglove's requirement)
    cc.options = {"preset": "ultrafast", "crf": str(CRF), "tune": "zerolatency",
                  "x264-params": "repeat-headers=1"}
    return cc


def camera_video(scene: Scene, cam: str, first: int, last: int) -> Iterator[tuple[int, bytes]]:
    """(scene frame, H.264 access unit, Annex B) of every video frame of ``cam`` in
    first..last, in order; nothing when the camera has no video."""
    import av

    cc = None
    frames: list[int] = []
    for f, img in imagery.video_frames(scene, cam, first, last):
        if cc is None:
            h, w = img.shape[0] // 2 * 2, img.shape[1] // 2 * 2
            cc = _encoder(w, h, scene.fps)
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img[:h, :w]), format="bgr24")
        vf.pts = len(frames)
        frames.append(f)
        for p in cc.encode(vf):
            yield frames[int(p.pts)], bytes(p)
    if cc is not None:
        for p in cc.encode(None):
            yield frames[int(p.pts)], bytes(p)


def video_streams(scene: Scene, cameras: list[str] | None = None) -> tuple:
    """``ExportOptions.extra_streams`` for the video of every frame: one stream per camera of
    foxglove.CompressedVideo messages on ``/cameras/<cam>/video``."""
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo

    from s2p_review.foxglove import timestamp

    def make(cam: str, rank: int):
        def stream(sel, tb):
            if cameras is None and cam not in sel.cameras:
                return
            for f, data in camera_video(scene, cam, sel.first, sel.last):
                ns = tb.ns1(f)
                yield ns, rank, f"/cameras/{cam}/video", CompressedVideo(
                    timestamp=timestamp(ns), frame_id=cam, data=data, format="h264")
        return stream

    cams = list(scene.cameras) if cameras is None else cameras
    return tuple(make(c, 90 + k) for k, c in enumerate(cams))


def export_annotated_mcap(scene: Scene, run_dir: Path, out_path: Path, journal: dict[str, bytes],
                          options: ExportOptions | None = None, force: bool = False,
                          video: bool = True) -> ExportResult:
    """``export_mcap`` of ``scene`` with the annotation run folder ``run_dir`` (annotated poses
    with their source column) plus ``journal`` (``annotations/<file>`` -> bytes) attached, the
    masks files attached and (``video``) every frame's video (module docstring)."""
    for name in journal:
        if _file_name(name) is None:
            raise ValueError(f"journal file {name!r} must be named {PREFIX}<file>")
    opts = options or ExportOptions()
    cams = opts.cameras
    extra = dict(opts.attachments or {})
    extra.update(journal)
    extra.update(scene_file_attachments(scene, cams or list(scene.cameras)))
    streams = tuple(opts.extra_streams) + (video_streams(scene, cams) if video else ())
    # the plain JPEG frames would repeat the H.264 channel
    opts = dataclasses.replace(opts, attachments=extra, extra_streams=streams,
                               video=opts.video and not video)
    return export_mcap(scene, run_dir, out_path, opts, force)


def restore_annotation_files(attachments: dict[str, bytes], folder: Path,
                             file: str | Path | None = None) -> list[Path]:
    """Write the ``annotations/<file>`` attachments into ``folder/annotations/``; returns the
    paths written. An attachment name that would leave that folder is an error naming it."""
    out = []
    for att, data in sorted(attachments.items()):
        name = _file_name(att, file)
        if name is None:
            continue
        path = Path(folder) / PREFIX.rstrip("/") / name
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)
        out.append(path)
    return out


def restore_scene_files(attachments: dict[str, bytes], folder: Path,
                        file: str | Path | None = None) -> list[Path]:
    """Write the ``scene-files/masks/<file>`` attachments into ``folder/masks/``."""
    out = []
    for att, data in sorted(attachments.items()):
        if not att.startswith(f"{SCENE_FILES}masks/"):
            continue
        name = safe_name(att[len(f"{SCENE_FILES}masks/"):], file=file, field=f"attachment {att}",
                         what="masks file name")
        path = Path(folder) / "masks" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)
        out.append(path)
    return out


def read_video(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Camera -> [(log time ns, H.264 access unit)] of an MCAP file's video channels."""
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo
    from mcap.reader import make_reader

    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = [c.topic for c in (summary.channels.values() if summary else ())
                  if VIDEO_TOPIC.match(c.topic)]
        if not topics:
            return out
        for _schema, channel, msg in reader.iter_messages(topics=topics, log_time_order=True):
            cam = channel.topic.split("/")[2]  # /cameras/<cam>/video
            out.setdefault(cam, []).append((msg.log_time, CompressedVideo.FromString(msg.data).data))
    return out


def restore_video(video: dict[str, list[tuple[int, bytes]]], folder: Path, fps: float,
                  start_ns: int, file: str | Path | None = None) -> dict[str, dict]:
    """Write each camera's H.264 messages as ``folder/video/<cam>.mp4`` (remuxed, not
    re-encoded) and name them in ``folder/scene.json`` (``videos``, and
    ``extra.video_frames``: the first frame); returns camera -> {"file", "first", "frames"}."""
    import av

    folder = Path(folder)
    done = {}
    rate = Fraction(fps).limit_denominator(1001)
    for cam, msgs in sorted(video.items()):
        safe_name(cam, file=file, field=f"/cameras/{cam}/video", what="camera name")
        frames = [int(round((ns - start_ns) * fps / 1e9)) for ns, _ in msgs]
        if np.any(np.diff(frames) != 1):
            raise InputError(f"/cameras/{cam}/video: the frames are not consecutive (frames "
                             f"{frames[0]}..{frames[-1]}, {len(frames)} messages)", file=file)
        rel = f"video/{cam}.mp4"
        (folder / "video").mkdir(parents=True, exist_ok=True)
        try:
            inp = av.open(io.BytesIO(b"".join(d for _, d in msgs)), "r", format="h264")
            ins = inp.streams.video[0]
            buf = io.BytesIO()
            out = av.open(buf, "w", format="mp4")
            outs = out.add_stream_from_template(ins)
            outs.time_base = 1 / rate
            n = 0
            for pk in inp.demux(ins):
                if pk.size == 0:
                    continue
                pk.pts = pk.dts = n
                pk.time_base = 1 / rate
                pk.stream = outs
                out.mux(pk)
                n += 1
            out.close()
            inp.close()
        except (av.error.FFmpegError, IndexError, ValueError) as e:
            raise InputError(f"/cameras/{cam}/video is not a readable H.264 stream ({e})",
                             file=file) from None
        atomic_write_bytes(folder / rel, buf.getvalue())
        done[cam] = {"file": rel, "first": frames[0], "frames": n}
    if done:
        scene_json = folder / "scene.json"
        d = json.loads(scene_json.read_text(encoding="utf-8"))
        d["videos"] = {**(d.get("videos") or {}), **{c: v["file"] for c, v in done.items()}}
        extra = d.setdefault("extra", {})
        vf = extra.get("video_frames") if isinstance(extra.get("video_frames"), dict) else {}
        vf.update({c: {"first": v["first"], "step": 1} for c, v in done.items()})
        extra["video_frames"] = vf
        from seg2pose.io.scene_schema import scene_fields

        try:  # the schema load_scene reads it with: a video of a camera the scene lacks is refused
            scene_fields(d, folder, scene_json)
        except InputError as e:
            raise InputError(f"the restored scene would be invalid (scene.json field {e.field}): "
                             f"{e.message}", file=file) from None
        atomic_write_bytes(scene_json, (json.dumps(d, indent=1) + "\n").encode())
    return done
