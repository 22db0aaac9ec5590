"""The shipped sample files (``make demo``): small, with video under the masks, real times, a
Foxglove layout that fits the MCAP, and `s2p screenshot` pictures of both files whose camera
views show the video (found by template matching of a frame decoded from the file itself)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from s2p_review import viewer as V
from s2p_review.foxglove_layout import layout_topics

LOGS = Path(__file__).resolve().parents[2] / "sample_logs"
RRD, MCAP, LAYOUT = LOGS / "demo.rrd", LOGS / "demo.mcap", LOGS / "demo.layout.json"
FRAME = 600  # the README picture's frame
START_NS = 1623657600 * 10**9  # the demo scene's start_time, 2021-06-14T08:00:00Z

pytestmark = pytest.mark.skipif(not (RRD.exists() and MCAP.exists()),
                                reason="sample_logs/ not made (make demo)")


@pytest.fixture(scope="module", autouse=True)
def _opencv_one_thread():
    """OpenCV on one thread in this module (its worker pool hangs processes forked later)."""
    from video_fixtures import single_threaded_opencv

    yield from single_threaded_opencv()



def _mcap_meta() -> dict:
    from mcap.reader import make_reader

    with open(MCAP, "rb") as f:
        return {m.name: m.metadata for m in make_reader(f).iter_metadata()}["s2p"]


def _display_frame(cam: str, frame: int) -> np.ndarray:
    """The display image (RGB) of ``cam`` at ``frame`` in the sample MCAP."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap.reader import make_reader

    meta = _mcap_meta()
    ns = int(meta["start_ns"]) + round(frame * 1e9 / float(meta["fps"]))
    with open(MCAP, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=[f"/cameras/{cam}/display"],
                                                      starting_at=ns, ending_before=ns + 1):
            msg = CompressedImage()
            msg.ParseFromString(m.data)
            return cv2.imdecode(np.frombuffer(msg.data, np.uint8), 1)[..., ::-1]
    raise AssertionError(f"no display image of {cam} at frame {frame}")


def _rrd_video_frame(frame: int) -> tuple[str, np.ndarray]:
    """(camera, RGB video frame) of the first camera with video at ``frame`` in the sample .rrd."""
    import rerun.chunk as rc

    for ch in rc.RrdReader(RRD).stream():
        if ch.is_static or not ch.entity_path.endswith("/image"):
            continue
        b = ch.to_record_batch()
        frames = b.column("frame").to_pylist()
        if frame in frames:
            blob = bytes(b.column("EncodedImage:blob").to_pylist()[frames.index(frame)][0])
            img = cv2.imdecode(np.frombuffer(blob, np.uint8), 1)[..., ::-1]
            return ch.entity_path.split("/")[3], img
    raise AssertionError(f"no video at frame {frame}")


def test_sample_files_are_small_and_carry_video_and_real_times():
    assert RRD.stat().st_size < 8e6 and MCAP.stat().st_size < 8e6
    meta = _mcap_meta()
    assert int(meta["start_ns"]) == START_NS and meta["start_time"] == "2021-06-14T08:00:00Z"
    cams = json.loads(LAYOUT.read_text())
    img = _display_frame("c0", FRAME)
    assert img.std() > 20 and img.mean() > 40  # a street scene, not black masks
    _, vid = _rrd_video_frame(FRAME)
    assert vid.std() > 20
    assert cams["configById"]


def test_sample_layout_names_topics_in_the_mcap():
    from mcap.reader import make_reader

    with open(MCAP, "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    named = layout_topics(json.loads(LAYOUT.read_text()))
    assert named <= topics, named - topics
    assert {t for t in named if t.endswith("/display")}


def _best_match(shot: np.ndarray, template: np.ndarray) -> float:
    """The best normalised correlation of ``template`` (grey) anywhere in ``shot`` over sizes
    from 10 % to 60 % of the screenshot's width."""
    g = cv2.cvtColor(shot.astype(np.uint8), cv2.COLOR_RGB2GRAY)
    t = cv2.cvtColor(template, cv2.COLOR_RGB2GRAY)
    best = -1.0
    for w in np.linspace(0.1, 0.6, 26) * g.shape[1]:
        h = int(round(w * t.shape[0] / t.shape[1]))
        if h >= g.shape[0] or w >= g.shape[1]:
            continue
        tt = cv2.resize(t, (int(w), h), interpolation=cv2.INTER_AREA)
        best = max(best, float(cv2.matchTemplate(g, tt, cv2.TM_CCOEFF_NORMED).max()))
    return best


@pytest.mark.skipif(V.vulkan_problem() is not None, reason="no Vulkan for the headless viewer")
@pytest.mark.parametrize("source", ["rrd", "mcap"])
def test_screenshot_of_sample_shows_video(source, tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    path = RRD if source == "rrd" else MCAP
    if source == "rrd":
        _, frame_img = _rrd_video_frame(FRAME)
    else:
        frame_img = _display_frame("c0", FRAME)
    png = tmp_path / "shot.png"
    r = CliRunner().invoke(app, ["screenshot", str(path), "-o", str(png), "--frame", str(FRAME)])
    assert r.exit_code == 0, r.output
    shot = cv2.imread(str(png))[..., ::-1]
    score = _best_match(shot, frame_img)
    assert score > 0.6, f"the video frame is not in the picture (best correlation {score:.2f})"
    # and not some other moment of the video
    if source == "mcap":
        assert score > _best_match(shot, _display_frame("c0", FRAME + 40)) + 0.02
