"""Cross-camera association on hand-made tracks (seg2pose.video.associate)."""

from __future__ import annotations

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.video.associate import AssociateConfig, CameraViews, associate, majority_class, position_spread

F = np.arange(100)


def path(x0, y0, x1, y1, frames=F):
    s = (frames - frames[0]) / max(frames[-1] - frames[0], 1)
    return np.stack([x0 + (x1 - x0) * s, y0 + (y1 - y0) * s], axis=1)


def cam(rows, bias, seed, spread=0.3):
    """rows: list of (track, class, frames, xy); bias: the camera's systematic shift (its
    default-height error), plus 5 cm noise."""
    rng = np.random.default_rng(seed)
    fr = np.concatenate([r[2] for r in rows])
    tr = np.concatenate([np.full(len(r[2]), r[0]) for r in rows])
    cl = np.concatenate([np.full(len(r[2]), r[1]) for r in rows])
    xy = np.concatenate([r[3] for r in rows]) + np.asarray(bias) + rng.normal(0, 0.05, (len(fr), 2))
    o = np.argsort(fr, kind="stable")
    return CameraViews(fr[o], tr[o], cl[o], xy[o], spread)


def same_id_per_frame(va, ia, ta, vb, ib, tb):
    """The ids camera a gives track ta and camera b track tb, frame by frame (common frames)."""
    fa = dict(zip(va.frame[va.track == ta].tolist(), ia[va.track == ta].tolist()))
    fb = dict(zip(vb.frame[vb.track == tb].tolist(), ib[vb.track == tb].tolist()))
    return [(fa[f], fb[f]) for f in sorted(set(fa) & set(fb))]


def test_crossing_road_users_keep_their_ids():
    # two pedestrians crossing on a 1 m wide path: 0.4 m apart for ~10 frames
    r1, r2 = path(0, 0, 20, 1), path(20, 0, 0, 1)
    a = cam([(1, 1, F, r1), (2, 1, F, r2)], (0.3, 0.2), 1)
    b = cam([(7, 1, F, r1), (3, 1, F, r2)], (-0.3, -0.2), 2)
    res = associate({"a": a, "b": b})
    ids = res.ids
    assert res.road_users == 2
    for ta, tb in ((1, 7), (2, 3)):
        pairs = same_id_per_frame(a, ids["a"], ta, b, ids["b"], tb)
        assert len(pairs) == 100 and all(x == y for x, y in pairs)
    assert len(np.unique(ids["a"][a.track == 1])) == 1  # never swapped over time
    assert ids["a"][a.track == 1][0] != ids["a"][a.track == 2][0]


def test_a_tracker_swap_is_cut_where_the_other_camera_says():
    # camera a's tracker follows road user 1 then jumps to road user 2 at frame 50 (and back)
    r1, r2 = path(0, 0, 20, 0), path(0, 6, 20, 6)
    lo, hi = F[F < 50], F[F >= 50]
    a = cam([(1, 1, lo, r1[:50]), (1, 1, hi, r2[50:]), (2, 1, lo, r2[:50]), (2, 1, hi, r1[50:])],
            (0.3, 0), 3)
    b = cam([(5, 1, F, r1), (6, 1, F, r2)], (-0.3, 0), 4)
    res = associate({"a": a, "b": b})
    assert res.cuts >= 2
    ib = res.ids["b"]
    id1, id2 = ib[b.track == 5][0], ib[b.track == 6][0]
    assert len(np.unique(ib[b.track == 5])) == 1 and id1 != id2
    ia = res.ids["a"]
    on_r1 = ((a.track == 1) & (a.frame < 50)) | ((a.track == 2) & (a.frame >= 50))
    assert (ia[on_r1] == id1).all() and (ia[~on_r1] == id2).all()


def test_road_user_leaving_one_camera_keeps_its_id_in_the_other():
    r1, r2 = path(0, 0, 30, 0), path(0, 8, 30, 8)
    a = cam([(1, 3, F, r1), (2, 1, F, r2)], (0.2, 0.3), 5)
    b = cam([(4, 3, F[:50], r1[:50]), (9, 1, F, r2)], (-0.2, 0.3), 6)  # leaves b's view at 50
    res = associate({"a": a, "b": b})
    ia, ib = res.ids["a"], res.ids["b"]
    assert len(np.unique(ia[a.track == 1])) == 1
    assert (ib[b.track == 4] == ia[a.track == 1][0]).all()
    assert (ib[b.track == 9] == ia[a.track == 2][0]).all()


def test_fragmented_track_is_joined_through_the_other_camera():
    # camera b loses road user 1 for 10 frames and finds it again under a new track
    r1 = path(0, 0, 30, 0)
    a = cam([(1, 1, F, r1)], (0.2, 0), 7)
    keep = (F < 40) | (F >= 50)
    f2 = F[keep]
    b = cam([(1, 1, f2[f2 < 40], r1[:40]), (2, 1, f2[f2 >= 50], r1[50:])], (-0.2, 0), 8)
    res = associate({"a": a, "b": b})
    assert res.road_users == 1
    assert len(np.unique(np.r_[res.ids["a"], res.ids["b"]])) == 1


def test_lone_camera_road_user_keeps_its_own_id():
    r1, r3 = path(0, 0, 30, 0), path(50, 50, 60, 50)
    a = cam([(1, 1, F, r1), (2, 3, F, r3)], (0.2, 0), 9)   # road user 3: only camera a
    b = cam([(1, 1, F, r1)], (-0.2, 0), 10)
    c = cam([(3, 1, F, r1)], (0, 0.2), 11)
    res = associate({"a": a, "b": b, "c": c})
    ia = res.ids["a"]
    lone = np.unique(ia[a.track == 2])
    assert len(lone) == 1
    assert lone[0] not in set(res.ids["b"]) | set(res.ids["c"]) | set(ia[a.track == 1])
    assert res.cameras_of_id[int(lone[0])] == ["a"]
    assert res.road_users == 2
    # tracks numbered 1 in both b and a are one road user here, but ids are unique over cameras
    assert len(set(res.ids["b"]) | set(res.ids["c"]) | set(ia[a.track == 1])) == 1


def test_no_camera_sees_one_road_user_twice_in_a_frame():
    # three road users close together in a row: whatever is joined, ids stay unique per frame
    rng = np.random.default_rng(0)
    rows_a = [(k, 1, F, path(0, 0.7 * k, 20, 0.7 * k)) for k in range(3)]
    rows_b = [(k + 10, 1, F, path(0, 0.7 * k, 20, 0.7 * k)) for k in range(3)]
    a = cam(rows_a, (0.3, 0.3), 12)
    b = cam(rows_b, (-0.3, -0.3), 13)
    res = associate({"a": a, "b": b}, AssociateConfig(gate_m=2.0))
    for c, v in (("a", a), ("b", b)):
        key = v.frame * 1000 + res.ids[c]
        assert len(np.unique(key)) == len(key)
    assert rng is not None


def test_spread_grows_with_distance_and_majority_class():
    s = position_spread(np.array([0.0, 0, 10]), np.array([[10.0, 0, 0], [40, 0, 0]]),
                        np.array([0.9, 0.9]), 0.3)
    assert s[0] == pytest.approx(0.3 * 10 / 9.1) and s[1] == pytest.approx(0.3 * 40 / 9.1)
    ids = {"a": np.array([1, 1, 2]), "b": np.array([1, 2, 2])}
    cls = {"a": np.array([3, 3, 0]), "b": np.array([1, 0, 0])}
    out = majority_class(ids, cls)
    assert out["a"].tolist() == [3, 3, 0] and out["b"].tolist() == [3, 0, 0]


def test_settings_from_scene_json():
    assert AssociateConfig.from_dict({"gate_m": 1.5}).gate_m == 1.5
    with pytest.raises(InputError, match="unknown setting"):
        AssociateConfig.from_dict({"gate": 1})
    with pytest.raises(InputError, match="true or false"):
        AssociateConfig.from_dict({"split_blobs": 1})


def test_id_consistency_known_answer():
    from seg2pose.eval.evaluate import id_consistency
    from seg2pose.io.poses import PoseTable

    gt = PoseTable(np.array([0, 0, 1]), np.array([1, 2, 1]), np.array(["car"] * 3, object),
                   np.array([[0.0, 0, 0], [10, 0, 0], [0, 0, 0]]), np.zeros(3))
    cams = np.array(list("aaabbcc"), object)
    frame = np.array([0, 0, 1, 0, 0, 0, 0])
    tid = np.array([7, 8, 7, 7, 9, 7, 8])
    xy = np.array([[0, 0], [10, 0], [0, 0], [0.1, 0], [10, 0], [0, 0.1], [10.1, 0]])
    share, n = id_consistency(frame, cams, tid, xy, gt)
    assert n == 2 and share == pytest.approx(5 / 6)  # road user 2: ids 8, 9, 8


def test_with_three_cameras_only_the_swapped_tracker_is_cut():
    r1, r2 = path(0, 0, 20, 0), path(0, 6, 20, 6)
    lo, hi = F[F < 50], F[F >= 50]
    a = cam([(1, 1, lo, r1[:50]), (1, 1, hi, r2[50:]), (2, 1, lo, r2[:50]), (2, 1, hi, r1[50:])],
            (0.3, 0), 14)
    b = cam([(5, 1, F, r1), (6, 1, F, r2)], (-0.3, 0), 15)
    c = cam([(8, 1, F, r1), (9, 1, F, r2)], (0, 0.3), 16)
    res = associate({"a": a, "b": b, "c": c})
    assert res.cuts == 2  # a's two tracks, once each; b and c untouched
    ib, ic, ia = res.ids["b"], res.ids["c"], res.ids["a"]
    id1, id2 = ib[b.track == 5][0], ib[b.track == 6][0]
    assert (ib[b.track == 5] == id1).all() and (ic[c.track == 8] == id1).all()
    assert (ib[b.track == 6] == id2).all() and (ic[c.track == 9] == id2).all()
    on_r1 = ((a.track == 1) & (a.frame < 50)) | ((a.track == 2) & (a.frame >= 50))
    assert (ia[on_r1] == id1).all() and (ia[~on_r1] == id2).all()
