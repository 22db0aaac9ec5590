"""Review shows the video frame the masks belong to: the scene's frame numbering
(``extra.video_frames`` of a video file, the numbers in an image folder's file names), not the
position of the image in the file. A UTOCS recording whose positions start at 40 with step 2 is
the case that was wrong."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from review_fixtures import make_run, make_scene

from s2p_review import imagery
from s2p_review.recording import LogStyle
from s2p_review.session import RecordOptions, record
from seg2pose.io.scene import load_scene

N_FRAMES = 12


def colour(f: int) -> tuple[int, int, int]:
    """BGR colour of scene frame f's image: 20 grey levels apart, so JPEG cannot blur them."""
    return 20 * f, 255 - 20 * f, 128


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    """OpenCV on one thread in this module (its worker pool hangs processes forked later)."""
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()


@pytest.fixture(scope="module")
def numbered(tmp_path_factory):
    """c0: a video whose k-th frame is scene frame 4 + 2k; c1: an image folder of frames
    5..11 named 000005.png..000011.png. Each image has ``colour(scene frame)``."""
    root = tmp_path_factory.mktemp("numbered")
    scene = make_scene(root / "scene", n_frames=N_FRAMES)
    cam = scene.cameras["c0"]
    (root / "scene" / "video" / "c1").mkdir(parents=True)
    vw = cv2.VideoWriter(str(root / "scene" / "video" / "c0.avi"), cv2.VideoWriter_fourcc(*"MJPG"),
                         10, (cam.width, cam.height))
    for f in range(4, N_FRAMES, 2):
        vw.write(np.full((cam.height, cam.width, 3), colour(f), np.uint8))
    vw.release()
    for f in range(5, N_FRAMES):
        cv2.imwrite(str(root / "scene" / "video" / "c1" / f"{f:06d}.png"),
                    np.full((cam.height, cam.width, 3), colour(f), np.uint8))
    d = json.loads((root / "scene" / "scene.json").read_text())
    d["extra"]["video_frames"] = {"c0": {"first": 4, "step": 2}}
    (root / "scene" / "scene.json").write_text(json.dumps(d))
    scene = load_scene(root / "scene")
    return scene, make_run(scene, root / "scene" / "out" / "run-base"), root


def _frame_of(bgr: np.ndarray) -> int:
    """The scene frame whose ``colour`` is the image's mean colour."""
    return int(round(float(bgr[..., 0].mean()) / 20))


def test_frames_carry_the_scene_numbering(numbered):
    scene, _, _ = numbered
    got = [(f, _frame_of(im)) for f, im in imagery.video_frames(scene, "c0", 0, N_FRAMES - 1)]
    assert got == [(f, f) for f in (4, 6, 8, 10)]
    # every 3rd frame counted from 5: 5, 8, 11 -> only 8 has a video frame
    assert [f for f, _ in imagery.video_frames(scene, "c0", 5, 11, every=3)] == [8]
    got = [(f, _frame_of(im)) for f, im in imagery.video_frames(scene, "c1", 6, 9)]
    assert got == [(f, f) for f in (6, 7, 8, 9)]
    assert list(imagery.video_frames(scene, "c1", 0, 4)) == []


@pytest.mark.parametrize("fmt", ["jpeg", "asset"])
def test_review_shows_the_right_frame_under_the_masks(numbered, fmt):
    """JPEG images at the scene's frames; or the video asset: each scene frame refers to the
    asset's frame of that scene frame, and the frames without video are blank."""
    import io

    import av
    import rerun.chunk as rc

    scene, base, root = numbered
    out = record(scene, [base], root / f"v-{fmt}.rrd",
                 RecordOptions(mask_every=1, video_every=1,
                               style=LogStyle(masks=False, video_format=fmt))).rrd
    seen: dict[str, dict[int, int]] = {"c0": {}, "c1": {}}
    blank: dict[str, list[int]] = {"c0": [], "c1": []}
    assets: dict[str, dict[int, np.ndarray]] = {}
    refs: dict[str, dict[int, int]] = {"c0": {}, "c1": {}}
    for ch in rc.RrdReader(out).stream():
        cam = ch.entity_path.split("/")[3] if ch.entity_path.endswith("/image") else None
        if cam not in seen:
            continue
        b = ch.to_record_batch()
        names = b.schema.names
        if ch.is_static and "AssetVideo:blob" in names:
            with av.open(io.BytesIO(bytes(b.column("AssetVideo:blob").to_pylist()[0][0]))) as c:
                st = c.streams.video[0]
                assets[cam] = {int(round(fr.pts * st.time_base * 1e9)): fr.to_ndarray(format="bgr24")
                               for fr in c.decode(st)}
        elif ch.is_static:
            continue
        elif "EncodedImage:blob" in names:
            for f, blob in zip(b.column("frame").to_pylist(), b.column("EncodedImage:blob").to_pylist()):
                img = cv2.imdecode(np.frombuffer(bytes(blob[0]), np.uint8), cv2.IMREAD_COLOR)
                seen[cam][int(f)] = _frame_of(img)
        elif "VideoFrameReference:timestamp" in names:
            for f, ts in zip(b.column("frame").to_pylist(),
                             b.column("VideoFrameReference:timestamp").to_pylist()):
                refs[cam][int(f)] = int(ts[0])
        else:
            blank[cam] += b.column("frame").to_pylist()
    if fmt == "asset":
        for cam, r in refs.items():
            seen[cam] = {f: _frame_of(assets[cam][ts]) for f, ts in r.items()}
        assert sorted(blank["c0"]) == [f for f in range(N_FRAMES) if f not in (4, 6, 8, 10)]
        assert sorted(blank["c1"]) == list(range(5))
    assert seen["c0"] == {f: f for f in (4, 6, 8, 10)}
    assert seen["c1"] == {f: f for f in range(5, N_FRAMES)}
