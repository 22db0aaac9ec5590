"""Review recordings' bad input and outputs: existing outputs kept, failed recordings leave
nothing, unreachable viewers, unreadable video, broken masks, no display."""

from __future__ import annotations

import pytest
from review_fixtures import NO_IMAGES, make_run, review_scene
from video_fixtures import single_threaded_opencv

from s2p_review.session import Targets, record
from seg2pose.core.errors import InputError, S2PError

_opencv_one_thread = pytest.fixture(scope="module", autouse=True)(single_threaded_opencv)
tiny = pytest.fixture(scope="module")(review_scene)



# --- bad input and outputs ---------------------------------------------------------------------------
def test_existing_output_refused_and_kept(tiny):
    scene, base, _, root = tiny
    p = root / "exists.rrd"
    p.write_bytes(b"keep me")
    with pytest.raises(S2PError, match="--force"):
        record(scene, [base], p)
    assert p.read_bytes() == b"keep me"
    record(scene, [base], Targets(rrd=p, force=True), NO_IMAGES)
    assert p.read_bytes() != b"keep me"


def test_failed_recording_leaves_nothing(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad2", cameras=["nope"])
    out = root / "never.rrd"
    with pytest.raises(InputError):
        record(scene, [bad], out)
    assert not out.exists()
    assert not [p for p in root.iterdir() if p.name.startswith(".never.rrd")]


def test_unreachable_viewer_url(tiny):
    from s2p_review.viewer import free_port

    scene, base, _, root = tiny
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    with pytest.raises(S2PError, match="no viewer answers"):
        record(scene, [base], Targets(connect=url))
    with pytest.raises(S2PError, match="bad viewer URL"):
        record(scene, [base], Targets(connect="http://nowhere"))


def test_unreadable_video(tiny, tmp_path):
    import shutil

    scene, base, _, _ = tiny
    from seg2pose.io.scene import load_scene

    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out"))
    (copy / "video" / "c0.mp4").write_bytes(b"not a video")
    s2 = load_scene(copy)
    with pytest.raises(InputError, match=r"c0.mp4.*cannot open video"):
        record(s2, [base], tmp_path / "v.rrd")
    assert not (tmp_path / "v.rrd").exists()


def test_nothing_to_do(tiny):
    scene, base, _, _ = tiny
    with pytest.raises(S2PError, match="nothing to do"):
        record(scene, [base], Targets())


def test_bad_rle_in_masks_named(tiny, tmp_path):
    import shutil

    from seg2pose.io.scene import load_scene

    scene, base, _, _ = tiny
    copy = tmp_path / "scene"
    shutil.copytree(scene.root, copy, ignore=shutil.ignore_patterns("out", "video"))
    lines = (copy / "masks" / "c0.txt").read_text().splitlines()
    parts = lines[7].split()
    lines[7] = " ".join(parts[:5] + ["0" + parts[5]])  # a leading zero-length run: too few pixels
    (copy / "masks" / "c0.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"c0.txt: frame 2, track 7: RLE covers"):
        record(load_scene(copy), [base], tmp_path / "bad.rrd")
    assert not (tmp_path / "bad.rrd").exists()


def test_spawn_without_display_is_a_clear_error(tiny, monkeypatch):
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("display variables are a Linux matter")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    scene, base, _, root = tiny
    with pytest.raises(S2PError, match="no display"):
        record(scene, [base], Targets(spawn=True))
