"""``s2p associate`` on a hand-made three-camera scene: merged blobs split, masks/ids.json, and
``s2p run`` refusing to fuse ids that were never associated."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seg2pose.core.errors import S2PError
from seg2pose.geometry.camera import Camera, Rig
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, load_scene
from seg2pose.io.track_ids import ids_status, mark_ids, read_ids
from seg2pose.method.pipeline import RunOptions, run_scene
from seg2pose.structures.masks import encode
from seg2pose.video.associate_scene import associate_scene

W, H, N = 320, 240, 30


def cameras():
    return {"a": Camera.look_at("a", [0, -20, 8], [0, 0, 0], 300, W, H),
            "b": Camera.look_at("b", [20, 0, 8], [0, 0, 0], 300, W, H),
            "c": Camera.look_at("c", [-20, 0.5, 8], [0, 0, 0], 300, W, H)}


def rect_mask(cam: Camera, xy) -> np.ndarray:
    """The image rectangle of an upright 0.6 x 0.6 x 1.75 m box at xy (a pedestrian)."""
    dx = np.array([-0.3, 0.3, 0.3, -0.3] * 2)
    dy = np.array([-0.3, -0.3, 0.3, 0.3] * 2)
    z = np.array([0] * 4 + [1.75] * 4)
    uv, _, _ = cam.project_points(np.column_stack([xy[0] + dx, xy[1] + dy, z]))
    x0, y0 = np.floor(uv.min(axis=0)).astype(int)
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int)
    m = np.zeros((H, W), bool)
    m[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = True
    return m


def make_scene(tmp_path, from_video=True):
    """Two pedestrians walking side by side along x, one behind the other as camera a sees
    them: a's tracker made one blob track of both; b and c see them apart."""
    cams = cameras()
    g = np.array([[x, y, 0.0] for x in range(-30, 31, 10) for y in range(-30, 31, 10)])
    scene = Scene(root=tmp_path, name="t", fps=10.0, rig=Rig(cams, {"all": list(cams)}),
                  ground_points=g, classes=[ClassSpec(c["id"], c["name"], c["default_height"])
                                            for c in DEFAULT_CLASSES],
                  extra={"source": {"format": "video"}} if from_video else {})
    scene.save(tmp_path)
    walkers = {1: lambda f: (-3 + 0.1 * f, -1.0), 2: lambda f: (-3 + 0.1 * f, 1.0)}
    tracks = {"a": {1: 4}, "b": {1: 1, 2: 2}, "c": {1: 6, 2: 5}}
    for c, cam in cams.items():
        rows = []
        for f in range(N):
            masks = {k: rect_mask(cam, walkers[k](f)) for k in walkers}
            if c == "a":
                rows.append((f, 4, 1, encode(masks[1] | masks[2])))
            else:
                rows += [(f, tracks[c][k], 1, encode(masks[k])) for k in walkers]
        t = MaskTable([r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows], H, W,
                      [r[3] for r in rows])
        write_mots(tmp_path / "masks" / f"{c}.txt", t)
    mark_ids(tmp_path / "masks", {c: "tracker" for c in cams})
    return load_scene(tmp_path)


def test_merged_blob_is_split_by_the_other_cameras(tmp_path):
    make_scene(tmp_path)
    res = associate_scene(tmp_path, log=lambda s: None)
    assert res.blobs.flagged == N and res.blobs.split == N
    a, b, c = (read_mots(tmp_path / "masks" / f"{x}.txt") for x in "abc")
    assert len(a) == 2 * N  # every blob became two masks
    ids_b = {int(t) for t in b.track_id}
    assert len(ids_b) == 2 and {int(t) for t in c.track_id} == ids_b == {int(t) for t in a.track_id}
    # each of a's parts is where b's mask of the same id says: the nearer walker (y = -1)
    # reaches lower in a's image
    from seg2pose.structures.masks import iou, rle_stats

    cams = cameras()
    for f in (0, N // 2, N - 1):
        sel_a, sel_b = np.flatnonzero(a.frame == f), np.flatnonzero(b.frame == f)
        # walker 1 (y = -1) in b: the mask that overlaps its rectangle
        m1 = encode(rect_mask(cams["b"], (-3 + 0.1 * f, -1.0)))
        o = iou([m1], [b.rles[i] for i in sel_b], H, W)[0]
        id1 = int(b.track_id[sel_b[np.argmax(o)]])
        # walker 1 is nearer camera a: its part reaches lower in a's image
        _, _, box = rle_stats([a.rles[i] for i in sel_a], H, W)
        assert int(a.track_id[sel_a[np.argmax(box[:, 3])]]) == id1
    assert read_ids(tmp_path / "masks")["a"]["ids"] == "associated"


def test_without_blob_splitting_the_blob_is_one_road_user(tmp_path):
    make_scene(tmp_path)
    res = associate_scene(tmp_path, cfg={"split_blobs": False}, log=lambda s: None)
    a = read_mots(tmp_path / "masks" / "a.txt")
    assert len(a) == N and len(np.unique(a.track_id)) == 1
    assert res.road_users == 2


def test_run_refuses_unassociated_ids_until_associated(tmp_path):
    scene = make_scene(tmp_path)
    with pytest.raises(S2PError, match="not associated across cameras.*s2p associate"):
        run_scene(scene, tmp_path / "run", RunOptions(config="all", baseline=True, progress=False))
    run_scene(scene, tmp_path / "run", RunOptions(config="all", baseline=True, progress=False,
              fuse_unassociated=True))
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["track_ids"]["ids"] == "unassociated" and meta["track_ids"]["fused_anyway"]
    associate_scene(tmp_path, log=lambda s: None)
    with pytest.raises(S2PError, match="associated already"):
        associate_scene(tmp_path, log=lambda s: None)
    run_scene(load_scene(tmp_path), tmp_path / "run", RunOptions(config="all", baseline=True,
              progress=False, force=True))
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["track_ids"]["ids"] == "associated"
    # masks changed after association: their ids are unknown again
    p = tmp_path / "masks" / "b.txt"
    p.write_text(p.read_text().replace("\n", "\n", 1) + "")
    lines = p.read_text().splitlines()
    p.write_text("\n".join(lines[:-1]) + "\n")
    kind, why = ids_status(tmp_path / "masks", ["a", "b", "c"], from_video=True)
    assert kind == "unassociated" and "changed" in why


def test_old_scenes_without_a_record_fuse_as_before(tmp_path):
    make_scene(tmp_path, from_video=False)
    (tmp_path / "masks" / "ids.json").unlink()
    assert ids_status(tmp_path / "masks", ["a", "b"])[0] == "given"
    run_scene(load_scene(tmp_path), tmp_path / "run", RunOptions(config="all", baseline=True, progress=False))
    meta = json.loads((tmp_path / "run" / "run.json").read_text())
    assert meta["track_ids"]["ids"] == "given"


def test_cli_associate_and_run_errors_are_one_line(tmp_path, monkeypatch, capsys):
    import sys

    from typer.testing import CliRunner

    from seg2pose.cli import app, main

    make_scene(tmp_path)
    monkeypatch.setattr(sys, "argv", ["s2p", "run", str(tmp_path), "-o", str(tmp_path / "run"),
                                      "--baseline"])
    with pytest.raises(SystemExit) as e:
        main()
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "not associated across cameras" in err and "s2p associate" in err
    r = CliRunner().invoke(app, ["associate", str(tmp_path), "--set", "gate=2"])
    assert r.exit_code != 0 and "unknown setting 'gate'" in str(r.exception)
    r = CliRunner().invoke(app, ["associate", str(tmp_path)])
    assert r.exit_code == 0 and "associated a, b, c: 2 road users" in r.output
    r = CliRunner().invoke(app, ["run", str(tmp_path), "-o", str(tmp_path / "run"), "--baseline"])
    assert r.exit_code == 0, r.output


def test_association_keeps_the_rest_of_the_masks_folder(tmp_path):
    make_scene(tmp_path)
    (tmp_path / "masks" / "notes.txt").write_text("mine\n")
    (tmp_path / "masks" / "extra").mkdir()
    (tmp_path / "masks" / "extra" / "x.json").write_text("{}")
    associate_scene(tmp_path, ["a", "b"], log=lambda s: None)
    assert (tmp_path / "masks" / "notes.txt").read_text() == "mine\n"
    assert (tmp_path / "masks" / "extra" / "x.json").read_text() == "{}"
    ids = read_ids(tmp_path / "masks")
    assert ids["a"]["with"] == ["a", "b"] and ids["c"]["ids"] == "tracker"
    assert ids_status(tmp_path / "masks", ["a", "b"])[0] == "associated"
    assert ids_status(tmp_path / "masks", ["a", "b", "c"])[0] == "unassociated"
