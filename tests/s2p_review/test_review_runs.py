"""The run folders a review shows: views read back, checks against the scene (cameras, frames,
another scene's run), run.json's metadata, bad views.csv lines named."""

from __future__ import annotations

import json

import numpy as np
import pytest
from review_fixtures import EST_OFFSET, N_FRAMES, TRACKS, make_run, review_scene
from video_fixtures import single_threaded_opencv

from s2p_review.runs import load_run, scene_last_frame
from seg2pose.core.errors import InputError
from seg2pose.io.mots import read_mots
from seg2pose.io.run import read_views

_opencv_one_thread = pytest.fixture(scope="module", autouse=True)(single_threaded_opencv)
tiny = pytest.fixture(scope="module")(review_scene)



# --- runs ------------------------------------------------------------------------------------------
def test_load_run_reads_views(tiny):
    scene, base, s2pn, _ = tiny
    run = load_run(s2pn, scene, scene_last_frame(scene))
    assert run.name == "run-s2pn" and run.cameras == ["c0", "c1"]
    assert run.frame_range == (0, N_FRAMES - 1)
    v = run.views
    assert len(v) == sum(len(read_mots(scene.masks_path(c))) for c in ("c0", "c1"))
    np.testing.assert_allclose(v.residual[0], [0.2, -0.2])
    np.testing.assert_allclose(run.poses.xyz[0] - EST_OFFSET,
                               np.r_[TRACKS[4][1], run.poses.xyz[0, 2]], atol=1e-12)


def test_scene_last_frame(tiny):
    assert scene_last_frame(tiny[0]) == N_FRAMES - 1


def test_run_with_unknown_camera_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad-cam", cameras=["c0", "c9"])
    with pytest.raises(InputError, match=r"c9.*lacks|lacks.*c9"):
        load_run(bad, scene, scene_last_frame(scene))


def test_run_beyond_scene_frames_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "bad-frames", frame_shift=100)
    with pytest.raises(InputError, match="frame"):
        load_run(bad, scene, scene_last_frame(scene))


def test_views_csv_errors_name_line(tmp_path):
    p = tmp_path / "views.csv"
    p.write_text("frame,track_id,camera,class,u,v,xn,yn,zn,dx,dy\n0,1,c0,car,1,2,3,4,5,6,7\n"
                 "1,1,c0,car,1,2,x,4,5,6,7\n")
    with pytest.raises(InputError, match=r"views.csv:3"):
        read_views(p)
    p.write_text("frame,track,camera\n")
    with pytest.raises(InputError, match=r"views.csv:1.*expected header"):
        read_views(p)


def test_run_json_meta_roundtrip(tiny, tmp_path):
    """run.json as read for review equals the file, and comes back equal through an MCAP export
    and import; a run.json without cameras takes them from views.csv."""
    import shutil

    from s2p_review.mcap_export import ExportOptions, export_mcap
    from s2p_review.mcap_import import import_mcap

    scene, base, _, _ = tiny
    on_disk = json.loads((base / "run.json").read_text())
    run = load_run(base, scene, scene_last_frame(scene))
    assert run.meta == on_disk and run.cameras == ["c0", "c1"]
    out = export_mcap(scene, base, tmp_path / "m.mcap", ExportOptions(frames=(0, 1))).path
    back = import_mcap(out, tmp_path / "restored")
    assert json.loads((back / "run.json").read_text()) == on_disk
    shutil.copytree(base, tmp_path / "nocams")
    meta = dict(on_disk, cameras=[])
    (tmp_path / "nocams" / "run.json").write_text(json.dumps(meta))
    v = read_views(base / "views.csv")
    (tmp_path / "nocams" / "views.csv").write_text(
        "\n".join([l for l in (base / "views.csv").read_text().splitlines() if ",c0," not in l]) + "\n")
    assert "c0" in set(v.camera.tolist())
    assert load_run(tmp_path / "nocams", scene).cameras == ["c1"]


def test_run_of_another_scene_is_rejected(tiny):
    scene, _, _, root = tiny
    bad = make_run(scene, root / "other-scene")
    meta = json.loads((bad / "run.json").read_text())
    meta["scene_fingerprint"] = "0123456789abcdef"
    (bad / "run.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="another scene"):
        load_run(bad, scene, scene_last_frame(scene))
