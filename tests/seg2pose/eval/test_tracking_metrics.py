"""HOTA, CLEAR MOT and IDF1 (seg2pose/eval/tracking_metrics.py, tracking_inputs.py): hand-made
cases whose figures are derived by hand below, and equality with TrackEval's own metric
classes (to 1e-9) on those and on random sequences when TrackEval is installed."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.eval.tracking_inputs import sequence_from_masks, sequence_from_poses
from seg2pose.eval.tracking_metrics import ALPHAS, Sequence, clear, hota, identity, summary
from seg2pose.io.mots import MaskTable
from seg2pose.io.poses import PoseTable
from seg2pose.structures.masks import encode


def poses(rows) -> PoseTable:
    """rows: (frame, track id, x, y)."""
    a = np.asarray(rows, float).reshape(-1, 4)
    return PoseTable(a[:, 0], a[:, 1], ["car"] * len(a), np.c_[a[:, 2:4], np.zeros(len(a))],
                     np.full(len(a), np.nan))


# Truth: road user A at x=0 in frames 0-3, B at x=10 in frames 0-1. Estimate: id 1 on A in
# frames 0-1, id 2 on A in frames 2-3 (one ID switch), id 3 on B in frame 0 only (B missed in
# frame 1), id 4 a false positive at x=50 in frame 3. Every similarity is 1 or 0.
TRUTH = poses([(0, 7, 0, 0), (1, 7, 0, 0), (2, 7, 0, 0), (3, 7, 0, 0), (0, 8, 10, 0), (1, 8, 10, 0)])
EST = poses([(0, 1, 0, 0), (1, 1, 0, 0), (2, 2, 0, 0), (3, 2, 0, 0), (0, 3, 10, 0), (3, 4, 50, 0)])


def test_hand_made_world_case():
    s = summary(sequence_from_poses(EST, TRUTH, d0=2.0))
    # CLEAR: GT = 6, TP = 5 (A four times, B once), FN = 1, FP = 1, IDSW = 1 (A: 1 -> 2);
    # MOTA = 1 - (1 + 1 + 1) / 6 = 0.5; MOTP = mean similarity of the TPs = 1
    assert (s["TP"], s["FN"], s["FP"], s["IDSW"]) == (5, 1, 1, 1)
    assert s["MOTA"] == pytest.approx(0.5, abs=1e-12) and s["MOTP"] == pytest.approx(1.0)
    # identity: one global pairing, A <-> 1 (or 2: 2 frames either way), B <-> 3 (1 frame):
    # IDTP = 3, IDFN = 6 - 3, IDFP = 6 - 3, IDF1 = 2 * 3 / (2 * 3 + 3 + 3) = 0.5
    assert (s["IDTP"], s["IDFN"], s["IDFP"]) == (3, 3, 3)
    assert s["IDF1"] == pytest.approx(0.5) and s["IDP"] == pytest.approx(0.5)
    # HOTA, the same at every alpha: DetA = 5 / (5 + 1 + 1); every TP's association Jaccard is
    # 0.5 (A-1: 2 / (2 + 2 + 0), A-2 the same, B-3: 1 / (1 + 1 + 0)), so AssA = 0.5;
    # HOTA = sqrt(5/7 * 0.5); AssRe = 0.5 (2/4, 2/4, 1/2), AssPr = 1 (2/2, 2/2, 1/1)
    assert s["DetA"] == pytest.approx(5 / 7) and s["AssA"] == pytest.approx(0.5)
    assert s["HOTA"] == pytest.approx(np.sqrt(5 / 14), abs=1e-12)
    assert s["DetRe"] == pytest.approx(5 / 6) and s["DetPr"] == pytest.approx(5 / 6)
    assert s["AssRe"] == pytest.approx(0.5) and s["AssPr"] == pytest.approx(1.0)
    assert s["LocA"] == pytest.approx(1.0)
    assert (s["gt_tracks"], s["est_tracks"], s["frames"]) == (2, 4, 4)


def test_distance_similarity_and_alphas():
    # one road user, one frame, 0.6 m off with d0 = 2 m: similarity 1 - 0.6 / 2 = 0.7
    seq = sequence_from_poses(poses([(5, 1, 0.6, 0)]), poses([(5, 9, 0, 0)]), d0=2.0)
    assert seq.similarity[0][0, 0] == pytest.approx(0.7)
    h = hota(seq)
    # a TP at the 14 alphas 0.05..0.70, a FN + FP at 0.75..0.95: HOTA_alpha 1 or 0
    np.testing.assert_allclose(h["HOTA"], (ALPHAS <= 0.7 + 1e-9).astype(float))
    s = summary(seq)
    assert s["HOTA"] == pytest.approx(14 / 19)
    # LocA at an alpha without matches is 1 in TrackEval (1e-10 / 1e-10): (14 * 0.7 + 5) / 19
    assert s["LocA"] == pytest.approx((14 * 0.7 + 5) / 19)
    assert s["MOTA"] == 1.0 and s["MOTP"] == pytest.approx(0.7) and s["sMOTA"] == pytest.approx(0.7)
    # 1.2 m off: similarity 0.4 < 0.5, no CLEAR match: MOTA = 1 - (1 + 1) / 1 = -1
    far = summary(sequence_from_poses(poses([(5, 1, 1.2, 0)]), poses([(5, 9, 0, 0)])))
    assert far["MOTA"] == pytest.approx(-1.0) and far["IDF1"] == 0.0


def rect(h, w, y0, y1, x0, x1) -> bytes:
    m = np.zeros((h, w), np.uint8)
    m[y0:y1, x0:x1] = 1
    return encode(m)


def frame_masks(f, ids, rles, h=40, w=60) -> tuple[int, MaskTable]:
    n = len(ids)
    return f, MaskTable(np.full(n, f), np.asarray(ids), np.ones(n, np.int64), h, w, list(rles))


def test_masks_iou_motsa_and_ignored_small_truth():
    big = rect(40, 60, 0, 10, 0, 10)              # 100 px
    half = rect(40, 60, 0, 10, 5, 15)             # IoU with big: 50 / 150 = 1/3
    tiny = rect(40, 60, 30, 32, 50, 52)           # 4 px truth mask: an ignore region at min_area 10
    truth = [frame_masks(0, [1, 2], [big, tiny]), frame_masks(1, [1], [big])]
    est = [frame_masks(0, [5, 6], [half, tiny]), frame_masks(1, [5], [big])]
    seq = sequence_from_masks(iter(truth), iter(est), min_area=10)
    # the estimate on the tiny truth mask is dropped with it: frame 0 has one truth, one estimate
    assert [len(g) for g in seq.gt_ids] == [1, 1] and [len(t) for t in seq.tracker_ids] == [1, 1]
    assert seq.similarity[0][0, 0] == pytest.approx(1 / 3) and seq.similarity[1][0, 0] == 1.0
    s = summary(seq, kind="masks")
    # CLEAR at IoU >= 0.5: frame 0 FN + FP, frame 1 TP: MOTSA = (1 - 1 - 0) / 2 = 0
    assert (s["TP"], s["FN"], s["FP"], s["IDSW"]) == (1, 1, 1, 0)
    assert s["MOTSA"] == 0.0 and s["MOTSP"] == 1.0 and "MOTA" not in s
    # HOTA: alphas <= 1/3 (0.05..0.30, six) match both frames: DetA 1, AssA 1; the other 13
    # match frame 1 only: DetA 1/3, and the one TP's Jaccard is 1 / (1 + 1 + 1) = 1/3
    expect = np.where(ALPHAS <= 1 / 3, 1.0, 1 / 3)
    assert s["HOTA"] == pytest.approx(float(np.mean(expect)))
    # without the ignore rule the tiny pair is an exact match: one more TP in frame 0
    s0 = summary(sequence_from_masks(iter(truth), iter(est)), kind="masks")
    assert (s0["TP"], s0["FN"], s0["FP"]) == (2, 1, 1)


def test_rows_without_a_position_are_no_detections():
    est = poses([(0, 1, 0, 0), (1, 1, np.nan, 0), (2, 2, 0, 0), (3, 2, 0, 0), (0, 3, 10, 0), (3, 4, 50, 0)])
    s = summary(sequence_from_poses(est, TRUTH))
    # as the hand-made case with A's frame 1 missed: one more FN, no IDSW on the way (1 -> 2 still one)
    assert (s["TP"], s["FN"], s["FP"], s["IDSW"]) == (4, 2, 1, 1) and s["est_dets"] == 5


def test_truth_in_view_of_the_run_cameras():
    from seg2pose.eval.tracking_inputs import in_view
    from seg2pose.geometry.camera import Camera

    cam = Camera.look_at("c", np.array([0.0, 0.0, 10.0]), np.array([10.0, 0.0, 0.0]), 100.0, 200, 100)
    # the point looked at (the image centre), one behind the camera, one 50 m to the side (its
    # pixel ~ 100 * 50 / 14 px off the centre, past the 100 px half width)
    p = poses([(0, 1, 10, 0), (0, 2, -10, 0), (0, 3, 10, 50)])
    assert in_view(p, [cam]).track_id.tolist() == [1]
    side = Camera.look_at("s", np.array([0.0, 0.0, 10.0]), np.array([10.0, 50.0, 0.0]), 100.0, 200, 100)
    assert in_view(p, [cam, side]).track_id.tolist() == [1, 3]


def test_empty_sides():
    none = poses([])
    s = summary(sequence_from_poses(none, TRUTH))
    assert (s["FN"], s["TP"], s["FP"]) == (6, 0, 0) and s["HOTA"] == 0.0 and s["IDF1"] == 0.0
    s = summary(sequence_from_poses(EST, none))
    assert (s["FP"], s["FN"]) == (6, 0) and s["MOTA"] == 0.0


def random_sequence(rng, frames=30, n_gt=6, n_tr=8) -> Sequence:
    """Road users that come and go, estimates that swap, miss and add, with real similarities."""
    gts, trs, sims = [], [], []
    for _ in range(frames):
        g = np.flatnonzero(rng.random(n_gt) < 0.6)
        t = np.flatnonzero(rng.random(n_tr) < 0.6)
        s = rng.random((len(g), len(t)))
        s[s < 0.4] = 0.0
        gts.append(g.astype(np.int64))
        trs.append(t.astype(np.int64))
        sims.append(s)
    return Sequence(gts, trs, sims, n_gt, n_tr, np.arange(frames))


def test_equal_to_trackeval():
    te = pytest.importorskip("trackeval.metrics")   # installed with --no-deps (Makefile)
    rng = np.random.default_rng(3)
    seqs = [sequence_from_poses(EST, TRUTH), random_sequence(rng), random_sequence(rng, 60, 12, 15),
            sequence_from_poses(poses([(5, 1, 0.6, 0)]), poses([(5, 9, 0, 0)]))]
    cfg = {"THRESHOLD": 0.5, "PRINT_CONFIG": False}
    for seq in seqs:
        data = seq.as_trackeval()
        ref_h = te.HOTA().eval_sequence(data)
        ref_c = te.CLEAR(cfg).eval_sequence(data)
        ref_i = te.Identity(cfg).eval_sequence(data)
        h, c, i = hota(seq), clear(seq), identity(seq)
        for k in ("HOTA", "DetA", "AssA", "LocA", "DetRe", "DetPr", "AssRe", "AssPr", "HOTA_TP"):
            np.testing.assert_allclose(h[k], ref_h[k], atol=1e-9, err_msg=k)
        for k in ("MOTA", "MOTP", "MODA", "sMOTA", "CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML",
                  "Frag"):
            assert c[k] == pytest.approx(ref_c[k], abs=1e-9), k
        for k in ("IDF1", "IDP", "IDR", "IDTP", "IDFN", "IDFP"):
            assert i[k] == pytest.approx(ref_i[k], abs=1e-9), k
    # identity's smaller assignment against TrackEval's square one on many shapes of sequence
    for n_gt, n_tr in [(1, 1), (2, 9), (9, 2), (5, 5), (20, 30), (40, 12)]:
        for _ in range(4):
            seq = random_sequence(rng, int(rng.integers(1, 40)), n_gt, n_tr)
            if seq.num_gt_dets and seq.num_tracker_dets:
                ref = te.Identity(cfg).eval_sequence(seq.as_trackeval())
                got = identity(seq)
                assert [got[k] for k in ("IDTP", "IDFN", "IDFP")] == [ref[k] for k in ("IDTP", "IDFN", "IDFP")]


def test_s2p_eval_json_carries_world_and_mask_metrics(tmp_path, monkeypatch, capsys):
    import json

    from scene_fixtures import make_tiny_scene, s2p

    from seg2pose.io.mots import read_mots, write_mots
    from seg2pose.io.poses import read_poses
    from seg2pose.io.run import write_run_folder

    scene = make_tiny_scene(tmp_path / "sc", frames=8, n_users=3)
    # the run: the truth itself, one road user's id changed from frame 4 on (one ID switch)
    gt = read_poses(scene.gt_path)
    est = read_poses(scene.gt_path)
    est.track_id[(est.track_id == 1) & (est.frame >= 4)] = 99
    run = tmp_path / "run"
    write_run_folder(run, est, None, {"scene_fingerprint": scene.fingerprint(), "method": "test"})
    # the masks: truth = the scene's masks of c1; the estimate swaps in the same id change
    truth = tmp_path / "truth" / "c1.txt"
    t = read_mots(scene.masks_path("c1"))
    write_mots(truth, t)
    t.track_id[(t.track_id == 1) & (t.frame >= 4)] = 99
    write_mots(scene.masks_path("c1"), t)
    code, out, err = s2p(monkeypatch, capsys, "eval", scene.root, "--run", run, "--truth-masks", truth, "--json")
    assert code in (0, None), err
    d = json.loads(out)
    w, m = d["tracking"], d["masks"]["c1"]
    n, n1 = len(gt.frame), int((gt.track_id == 1).sum())
    # every position exact: TP = n, one IDSW; MOTA = 1 - 1 / n; IDF1 = 2 IDTP / 2n with IDTP = n - 4
    # (road user 1's four frames 4..7 go to the unpaired id 99)
    assert (w["TP"], w["FP"], w["FN"], w["IDSW"]) == (n, 0, 0, 1) and n1 == 8
    assert w["MOTA"] == pytest.approx(1 - 1 / n) and w["IDF1"] == pytest.approx((n - 4) / n)
    assert w["LocA"] == pytest.approx(1.0) and w["similarity"] == "max(0, 1 - d / 2 m)"
    # HOTA: DetA 1; AssA = (4 * 4/8 + 4 * 4/8 + (n - 8) * 1) / n
    assert w["HOTA"] == pytest.approx(np.sqrt((4 * 0.5 + 4 * 0.5 + n - 8) / n))
    k = int((t.track_id == 99).sum())
    assert m["IDSW"] == 1 and m["MOTSA"] == pytest.approx(1 - 1 / len(t.frame)) and m["FP"] == 0
    assert m["IDF1"] == pytest.approx((len(t.frame) - min(k, int((t.track_id == 1).sum()))) / len(t.frame))
    assert d["mean_error"] == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 25), st.integers(1, 8), st.integers(1, 8))
def test_properties(seed, frames, n_gt, n_tr):
    rng = np.random.default_rng(seed)
    seq = random_sequence(rng, frames, n_gt, n_tr)
    s = summary(seq)
    for k in ("HOTA", "DetA", "AssA", "IDF1", "IDP", "IDR", "DetRe", "DetPr"):
        assert 0.0 <= s[k] <= 1.0, k
    assert s["MOTA"] <= 1.0 and s["TP"] + s["FN"] == seq.num_gt_dets and s["TP"] + s["FP"] == seq.num_tracker_dets
    assert s["IDTP"] <= min(seq.num_gt_dets, seq.num_tracker_dets)
    # the estimated ids' names do not matter
    perm = rng.permutation(n_tr)
    renamed = Sequence(seq.gt_ids, [perm[t] for t in seq.tracker_ids], seq.similarity, n_gt, n_tr, seq.frames)
    assert summary(renamed) == pytest.approx(s, abs=1e-12)
    # the truth against itself: every metric perfect
    same = Sequence(seq.gt_ids, seq.gt_ids, [np.eye(len(g)) for g in seq.gt_ids], n_gt, n_gt, seq.frames)
    p = summary(same)
    if seq.num_gt_dets:
        assert p["HOTA"] == p["IDF1"] == p["MOTA"] == p["LocA"] == 1.0 and p["IDSW"] == 0
