"""Synthetic scenes: truth inside masks, determinism, ground points on the surface, readers,
validation, the paper's association (one frame's rendering: test_render.py; rough models:
test_rough.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.mots import read_mots
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import load_scene
from seg2pose.structures.masks import decode, rle_stats
from seg2pose.synth import junction as J
from seg2pose.synth.generate import SynthOptions, generate_scene, split_ranges
from seg2pose.synth.noise import NoiseConfig
from seg2pose.synth.rig import CONFIGS, make_device


def _scene(tmp_path_factory, name: str, frames: int = 6, seed: int = 3, **kw) -> Path:
    out = tmp_path_factory.mktemp("synth") / name
    generate_scene(out, SynthOptions(frames=frames, seed=seed, progress=False, workers=1, **kw))
    return out


@pytest.fixture(scope="module")
def clean_scene(tmp_path_factory) -> Path:
    return _scene(tmp_path_factory, "clean", noise=NoiseConfig.off(), match="all")


@pytest.fixture(scope="module")
def noisy_scene(tmp_path_factory) -> Path:
    return _scene(tmp_path_factory, "noisy")


@pytest.fixture(scope="module")
def noisy_scene_40(tmp_path_factory) -> Path:
    return _scene(tmp_path_factory, "noisy40", frames=40, seed=0)


def test_scene_opens_with_the_readers(clean_scene):
    s = load_scene(clean_scene)
    assert list(s.cameras) == ["c0", "c1", "c2", "c3", "c4"]
    assert s.rig.configs == CONFIGS
    assert set(s.rig.configs) == {"mono-1", "mono-2", "mono-3", "stereo-10", "stereo-30",
                                  "stereo-40", "tri-I", "tri-L", "tri-T"}
    assert [(c.id, c.name) for c in s.classes] == [(1, "pedestrian"), (2, "bicyclist"), (3, "car")]
    assert s.splits == split_ranges(6, 1)
    assert abs(s.fps - 1 / 0.075) < 1e-9
    gen = s.extra["generator"]
    assert gen["seed"] == 3 and gen["noise"]["enabled"] is False and gen["match"] == "all"
    assert set(s.extra["class_sizes"]) == {"pedestrian", "bicyclist", "car"}
    assert len(s.ground_points) == 184
    gt = read_poses(s.gt_path, known_classes=[c.name for c in s.classes])
    assert gt.size is not None and (gt.size > 0).all()
    assert gt.frame.min() == 0 and gt.frame.max() == s.splits["test"][1]
    ids_by_cam = {}
    for c in s.cameras:
        m = read_mots(s.masks_path(c), known_classes=[1, 2, 3])
        assert (m.height, m.width) == (720, 1280) and len(m) > 0
        ids_by_cam[c] = set(zip(m.frame.tolist(), m.track_id.tolist()))
        # each detection is a road user of that frame in the truth, with the same class
        truth = {(f, t): k for f, t, k in zip(gt.frame, gt.track_id, gt.cls)}
        names = {1: "pedestrian", 2: "bicyclist", 3: "car"}
        for f, t, k in zip(m.frame, m.track_id, m.class_id):
            assert truth[(f, t)] == names[k]
    # late fusion needs the same id for the same road user in every camera
    common = set.intersection(*ids_by_cam.values())
    assert len(common) > 0.8 * len(ids_by_cam["c1"])


def test_stereo_baselines_match_names():
    rig = make_device()
    c = {n: cam.center for n, cam in rig.cameras.items()}
    for cfg, base in (("stereo-10", 0.10), ("stereo-30", 0.30), ("stereo-40", 0.40)):
        a, b = rig.configs[cfg]
        assert abs(np.linalg.norm(c[a] - c[b]) - base) < 1e-9
    i0, i1, i2 = (c[n] for n in rig.configs["tri-I"])
    assert np.linalg.norm(np.cross(i1 - i0, i2 - i0)) < 1e-12  # collinear
    l0, l1, l2 = (c[n] for n in rig.configs["tri-L"])
    assert abs(np.dot(l0 - l1, l2 - l1)) < 1e-12  # right angle at the middle lens


def test_ground_truth_projects_inside_its_mask(clean_scene):
    s = load_scene(clean_scene)
    gt = read_poses(s.gt_path)
    key = {(f, t): i for i, (f, t) in enumerate(zip(gt.frame, gt.track_id))}
    hits = n = 0
    for c, cam in s.cameras.items():
        m = read_mots(s.masks_path(c))
        area, _, _ = rle_stats(m.rles, m.height, m.width)
        for f, t, r, a in zip(m.frame, m.track_id, m.rles, area):
            if a < 200:
                continue
            i = key[(f, t)]
            centre = gt.xyz[i] + [0, 0, 0.5 * gt.size[i, 2]]
            uv, _, _ = cam.project_points(centre)
            x, y = np.floor(uv[0]).astype(int)
            if not (0 <= x < m.width and 0 <= y < m.height):
                continue
            mask = decode(r, m.height, m.width)
            n += 1
            hits += bool(mask[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].any())
    assert n > 50
    assert hits / n > 0.93  # misses: the centre hidden behind a nearer road user


def test_same_seed_same_bytes(tmp_path):
    a, b, c = tmp_path / "a" / "s", tmp_path / "b" / "s", tmp_path / "c" / "s"  # name is in scene.json
    generate_scene(a, SynthOptions(frames=4, seed=9, progress=False, workers=1))
    generate_scene(b, SynthOptions(frames=4, seed=9, progress=False, workers=2))  # process count must not matter
    generate_scene(c, SynthOptions(frames=4, seed=10, progress=False, workers=1))
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert {str(f) for f in files} >= {"scene.json", "ground_points.csv", "gt/poses.csv",
                                       "masks/c0.txt", "masks/c4.txt"}
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "masks/c1.txt").read_bytes() != (c / "masks/c1.txt").read_bytes()


def test_ground_points_lie_on_the_rendered_surface(clean_scene):
    s = load_scene(clean_scene)
    p = s.ground_points
    assert np.abs(p[:, 2] - J.true_height(p[:, :2])).max() < 1e-12
    near_curb = np.abs(J.curb_distance(p[:, :2])) < 0.5
    assert near_curb.mean() > 0.5  # denser along the curb edges, as in the paper
    on_sidewalk = J.curb_distance(p[:, :2]) > 0  # the raised sidewalk
    assert on_sidewalk.any() and (~on_sidewalk).any()
    # and road users stand on the same surface
    gt = read_poses(s.gt_path)
    assert np.abs(gt.xyz[:, 2] - J.true_height(gt.xyz[:, :2])).max() < 1e-12


def test_surface_has_curbs_and_a_slope():
    assert abs(J.true_height(np.array([[20.0, 9.0]]))[0] - J.true_height(np.array([[20.0, 5.0]]))[0]
               - J.CURB) < 1e-9
    assert J.true_height(np.array([[0.0, 0.0]]))[0] < 0.01
    z = J.true_height(np.array([[30.0, 0.0], [40.0, 0.0]]))
    assert 0.3 < z[1] - z[0] < 0.5  # about 4 % along the east arm


def test_noise_changes_masks_but_keeps_ids(clean_scene, noisy_scene):
    a = read_mots(clean_scene / "masks" / "c1.txt")
    b = read_mots(noisy_scene / "masks" / "c1.txt")
    assert len(b) <= len(a) * 1.05 and len(b) > 0.6 * len(a)
    pa = set(zip(a.frame.tolist(), a.track_id.tolist()))
    pb = set(zip(b.frame.tolist(), b.track_id.tolist()))
    assert pb <= pa  # noise never invents road users
    assert a.rles != b.rles
    s = json.loads((noisy_scene / "scene.json").read_text())
    assert s["extra"]["generator"]["noise"] == NoiseConfig().to_dict()


# --- bad input ------------------------------------------------------------------------------
def test_validation_before_any_work(tmp_path):
    out = tmp_path / "s"
    with pytest.raises(InputError, match="field 'frames'"):
        generate_scene(out, SynthOptions(frames=0, progress=False))
    with pytest.raises(InputError, match="field 'rig'"):
        generate_scene(out, SynthOptions(rig="nope", frames=2, progress=False))
    with pytest.raises(InputError, match="field 'preset'"):
        generate_scene(out, SynthOptions(preset="huge", progress=False))
    with pytest.raises(InputError, match="population"):
        generate_scene(out, SynthOptions(frames=2, population={"car": -1}, progress=False))
    with pytest.raises(InputError, match="noise.miss_rate"):
        generate_scene(out, SynthOptions(frames=2, noise=NoiseConfig(miss_rate=1.5), progress=False))
    # a rig looking at the sky sees no road
    from seg2pose.geometry.camera import Camera
    sky = Camera.look_at("up", np.array([0.0, 0.0, 10.0]), np.array([0.0, 50.0, 40.0]), 900, 1280, 720)
    rig_file = tmp_path / "sky.json"
    rig_file.write_text(json.dumps({"cameras": [sky.to_dict()]}))
    with pytest.raises(InputError, match="sees the road"):
        generate_scene(out, SynthOptions(rig=rig_file, frames=2, progress=False))
    # a camera with a negative image size is refused, naming the field
    d = sky.to_dict()
    d["width"] = -1280
    rig_file.write_text(json.dumps({"cameras": [d]}))
    with pytest.raises(InputError, match="width"):
        generate_scene(out, SynthOptions(rig=rig_file, frames=2, progress=False))
    with pytest.raises(InputError, match="field 'frames'"):
        generate_scene(out, SynthOptions(frames=-5, progress=False))
    assert not out.exists()


def test_never_overwrites_without_force_and_interruptions_leave_nothing(tmp_path, monkeypatch):
    out = tmp_path / "s"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(S2PError, match="--force"):
        generate_scene(out, SynthOptions(frames=2, progress=False))
    assert (out / "keep.txt").read_text() == "mine"

    import seg2pose.synth.generate as G

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(G, "_mask_task", boom)
    with pytest.raises(KeyboardInterrupt):
        generate_scene(out, SynthOptions(frames=2, progress=False, force=True, workers=1))
    assert (out / "keep.txt").read_text() == "mine"  # the old scene is untouched
    assert [p.name for p in tmp_path.iterdir()] == ["s"]  # no partial folder left behind
    monkeypatch.undo()
    generate_scene(out, SynthOptions(frames=2, progress=False, force=True, workers=1))
    assert not (out / "keep.txt").exists() and (out / "scene.json").exists()


def test_cli_synth(tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    r = CliRunner().invoke(app, ["synth", "-o", str(tmp_path / "s"), "--frames", "2", "--no-progress",
                                 "--workers", "1"])
    assert r.exit_code == 0, r.output
    assert load_scene(tmp_path / "s").splits["train"] == (0, 1)
    r = CliRunner().invoke(app, ["synth", "-o", str(tmp_path / "s"), "--frames", "2", "--no-progress"])
    assert r.exit_code != 0 and "--force" in str(r.exception)


def small_rig_file(tmp_path) -> Path:
    """One 320x180 camera where the device's middle lens is (cheap to render)."""
    from seg2pose.geometry.camera import Camera
    small = Camera.look_at("v", np.array([-12.0, -12.0, 10.0]), np.array([1.0, 1.0, 0.0]), 225.0, 320, 180)
    rig_file = tmp_path / "rig.json"
    rig_file.write_text(json.dumps({"cameras": [small.to_dict()], "configs": {"mono-1": ["v"]}}))
    return rig_file


def test_every_visit_has_its_own_id_and_keeps_its_size(tmp_path):
    """A road user that leaves and comes back is a new track (id) to a tracker: one id per
    visit, each with one class, one size and no gap in its frames; a returning road user keeps
    its size (its shape: the pixels do not depend on the ids)."""
    out = tmp_path / "s"
    pop = {"pedestrian": 3, "bicyclist": 1, "car": 4}
    generate_scene(out, SynthOptions(frames=600, seed=1, population=pop, progress=False, workers=1,
                   noise=NoiseConfig.off(), rig=small_rig_file(tmp_path)))
    gt = read_poses(out / "gt" / "poses.csv")
    ids = np.unique(gt.track_id)
    assert len(ids) > sum(pop.values())  # more visits than road users: some came back
    for t in ids:
        m = gt.track_id == t
        assert len(set(gt.cls[m])) == 1
        assert np.ptp(gt.size[m], axis=0).max() == 0.0
        assert np.diff(gt.frame[m]).max(initial=1) == 1  # one visit: no gap
    # no frame lists a road user twice
    pairs = np.stack([gt.frame, gt.track_id], 1)
    assert len(np.unique(pairs, axis=0)) == len(pairs)
    s = json.loads((out / "scene.json").read_text())
    assert s["extra"]["generator"]["ids"] == "road_user"
    assert sum(s["extra"]["road_users"].values()) == sum(pop.values())
    # the returning road users: as many distinct sizes as road users, fewer than visits
    sizes = {tuple(gt.size[gt.track_id == t][0]) for t in ids}
    assert len(sizes) <= sum(pop.values()) < len(ids)


def test_moving_road_users_head_where_they_go(clean_scene):
    gt = read_poses(clean_scene / "gt" / "poses.csv")
    o = np.lexsort((gt.frame, gt.track_id))
    t, f, xy, h = gt.track_id[o], gt.frame[o], gt.xyz[o, :2], gt.heading[o]
    same = (t[1:] == t[:-1]) & (f[1:] == f[:-1] + 1)
    step = xy[1:] - xy[:-1]
    moving = same & (np.linalg.norm(step, axis=1) > 0.05)
    assert moving.sum() > 100
    ang = np.arctan2(step[moving, 1], step[moving, 0])
    err = np.angle(np.exp(1j * (ang - h[:-1][moving])))
    assert np.percentile(np.abs(err), 95) < 0.35


def test_video_frames(tmp_path):
    import cv2

    from seg2pose.synth.rig import load_rig
    rig_file = small_rig_file(tmp_path)
    small = load_rig(rig_file).cameras["v"]
    out = tmp_path / "s"
    generate_scene(out, SynthOptions(frames=3, seed=2, rig=rig_file, video=True, progress=False, workers=1))
    cap = cv2.VideoCapture(str(out / "video" / "v.mp4"))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    assert len(frames) == 3 * 3 + 2 and frames[0].shape == (180, 320, 3)
    # road users are drawn where their masks are: the masked pixels differ from the empty scene
    from seg2pose.synth.video import background
    bg = background(small).astype(int)
    m = read_mots(out / "masks" / "v.txt")
    assert len(m) > 0, "the scene should have road users in view"
    # every frame with masks: video frame k shows frame k's road users
    for k in np.unique(m.frame):
        fk = m.take(m.frame == k)
        fg = np.zeros((180, 320), bool)
        for r in fk.rles:
            fg |= decode(r, 180, 320).astype(bool)
        assert fg.sum() >= 20  # enough pixels for the means below
        diff = np.abs(frames[int(k)].astype(int) - bg).sum(axis=2)
        assert diff[fg].mean() > 3 * diff[~fg].mean()
    assert not list(tmp_path.glob("**/.*partial*"))


def test_cli_noise_knobs_and_distortion(tmp_path):
    from typer.testing import CliRunner

    from seg2pose.cli import app

    out = tmp_path / "s"
    r = CliRunner().invoke(app, ["synth", "-o", str(out), "--frames", "2", "--no-progress", "--workers", "1",
                                 "--noise", "miss_rate=0.5", "--noise", "min_area=10",
                                 "--distortion", "-0.05,0.01"])
    assert r.exit_code == 0, r.output
    s = load_scene(out)
    gen = s.extra["generator"]
    assert gen["noise"]["miss_rate"] == 0.5 and gen["noise"]["min_area"] == 10
    assert gen["distortion"] == [-0.05, 0.01]
    cam = s.cameras["c1"]
    assert cam.distortion is not None and cam.distortion.k1 == -0.05
    bad = CliRunner().invoke(app, ["synth", "-o", str(tmp_path / "t"), "--noise", "speed=3"])
    assert bad.exit_code != 0 and "--noise" in str(bad.exception)
    bad = CliRunner().invoke(app, ["synth", "-o", str(tmp_path / "t"), "--distortion", "5,0"])
    assert bad.exit_code != 0 and "--distortion" in str(bad.exception)
    # a third number is refused, not dropped (the wide preset's device would keep two)
    for three in (["--distortion", "0.1,0,0.3"], ["--preset", "wide", "--distortion", "0.1,0,0.3"]):
        bad = CliRunner().invoke(app, ["synth", "-o", str(tmp_path / "t"), *three])
        assert bad.exit_code != 0 and "expected K1,K2 numbers" in str(bad.exception)
    assert not (tmp_path / "t").exists()


def test_truth_inside_masks_with_lens_distortion(tmp_path):
    out = tmp_path / "d"
    generate_scene(out, SynthOptions(frames=2, seed=4, noise=NoiseConfig.off(), progress=False, workers=1,
                   distortion=(-0.08, 0.0)))
    s = load_scene(out)
    gt = read_poses(s.gt_path)
    key = {(f, t): i for i, (f, t) in enumerate(zip(gt.frame, gt.track_id))}
    cam = s.cameras["c1"]
    m = read_mots(s.masks_path("c1"))
    area, _, _ = rle_stats(m.rles, m.height, m.width)
    hits = n = 0
    for f, t, r, a in zip(m.frame, m.track_id, m.rles, area):
        i = key[(f, t)]
        uv, _, _ = cam.project_points(gt.xyz[i] + [0, 0, 0.5 * gt.size[i, 2]])
        x, y = np.floor(uv[0]).astype(int)
        if a < 200 or not (0 <= x < m.width and 0 <= y < m.height):
            continue
        n += 1
        hits += bool(decode(r, m.height, m.width)[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].any())
    assert n > 10 and hits / n > 0.9


def test_center_matching_keeps_only_masks_covering_the_centre(clean_scene, tmp_path):
    out = tmp_path / "m"
    generate_scene(out, SynthOptions(frames=6, seed=3, noise=NoiseConfig.off(), progress=False, workers=1))
    s = load_scene(out)
    assert s.extra["generator"]["match"] == "center"
    gt = read_poses(s.gt_path)
    key = {(f, t): i for i, (f, t) in enumerate(zip(gt.frame, gt.track_id))}
    for c in ("c0", "c4"):
        allm = read_mots(clean_scene / "masks" / f"{c}.txt")
        kept = read_mots(s.masks_path(c))
        all_rows = {(f, t): r for f, t, r in zip(allm.frame, allm.track_id, allm.rles)}
        dropped = set(all_rows) - set(zip(kept.frame, kept.track_id))
        assert 0 < len(dropped) < 0.3 * len(all_rows)
        cam = s.cameras[c]
        for (f, t), r in all_rows.items():
            i = key[(f, t)]
            uv, _, _ = cam.project_points(gt.xyz[i] + [0, 0, 0.5 * gt.size[i, 2]])
            x, y = np.floor(uv[0]).astype(int)
            inside = 0 <= x < cam.width and 0 <= y < cam.height and decode(r, cam.height, cam.width)[y, x]
            assert bool(inside) == ((f, t) not in dropped)


def test_center_matching_holds_for_the_masks_as_written_with_noise(noisy_scene_40):
    """Paper 4.1 on the noisy, clipped masks: every kept detection has its road user's class
    and covers the projection of the true centre, which lies inside the image; and the
    association of seg2pose.method.matching (used for training) recovers exactly these ids."""
    from seg2pose.method.matching import match_masks_to_truth

    s = load_scene(noisy_scene_40)
    gt = read_poses(s.gt_path)
    key = {(f, t): i for i, (f, t) in enumerate(zip(gt.frame, gt.track_id))}
    names = {c.id: c.name for c in s.classes}
    n = 0
    for c in s.cameras:
        cam = s.cameras[c]
        m = read_mots(s.masks_path(c))
        idx = np.array([key[(f, t)] for f, t in zip(m.frame, m.track_id)])
        uv, _, front = cam.project_points(gt.xyz[idx] + np.outer(0.5 * gt.size[idx, 2], [0, 0, 1]))
        assert front.all() and cam.in_image(uv).all()
        for r, (x, y) in zip(m.rles, np.floor(uv).astype(int)):
            assert decode(r, cam.height, cam.width)[y, x]
        assert [names[int(k)] for k in m.class_id] == list(gt.cls[idx])
        assert (match_masks_to_truth(cam, m, gt, names) == idx).mean() > 0.99
        n += len(m)
    assert n > 100
