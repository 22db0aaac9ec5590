"""The mask tracker on masks with known identities."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.core.errors import InputError
from seg2pose.eval.mask_eval import score_masks
from seg2pose.geometry.camera import Camera
from seg2pose.geometry.ground import GroundSurface
from seg2pose.io.mots import MaskTable, read_mots, write_mots
from seg2pose.structures.masks import encode
from seg2pose.video.track import TrackConfig, Tracker, track_mots, track_table, world_positions

H, W = 120, 160


def box(x0, y0, w, h):
    m = np.zeros((H, W), np.uint8)
    m[max(int(y0), 0):max(int(y0 + h), 0), max(int(x0), 0):max(int(x0 + w), 0)] = 1
    return encode(m)


def table(rows):
    """rows: (frame, truth id, (x0, y0, w, h)) -> MaskTable with the truth id as class_id
    (so that tests can see which road user each tracked mask came from)."""
    rows = sorted(rows, key=lambda r: (r[0], r[1]))
    return MaskTable([r[0] for r in rows], [-1] * len(rows), [r[1] for r in rows], H, W,
                     [box(*r[2]) for r in rows])


def ids_by_truth(t):
    return {int(c): sorted(set(t.track_id[t.class_id == c].tolist())) for c in np.unique(t.class_id)}


def flat_scene():
    g = [(x, y, 0.0) for x in range(-20, 21, 10) for y in range(-20, 41, 10)]
    ground = GroundSurface(np.array(g, float))
    cam = Camera.look_at("c0", np.array([0.0, -10.0, 8.0]), np.array([0.0, 10.0, 0.0]), 150.0, W, H)
    return cam, ground


def test_occlusion_gap_keeps_identity_and_short_tracks_are_dropped():
    rows = []
    for f in range(30):
        rows.append((f, 1, (10 + f, 20, 20, 20)))                 # slow, always visible
        if not 10 <= f <= 13:                                      # hidden 4 frames
            rows.append((f, 2, (120 - f, 70, 20, 20)))
        if 5 <= f <= 7:
            rows.append((f, 3, (70, 5, 8, 8)))                     # a 3-frame blip
    t = track_table(table(rows), cfg=TrackConfig(min_length=5))
    assert ids_by_truth(t) == {1: [1], 2: [2]}                     # blip dropped, ids 1.. in order
    assert len(t) == 30 + 26
    # deterministic: the same input gives the same ids
    t2 = track_table(table(rows), cfg=TrackConfig(min_length=5))
    assert np.array_equal(t.track_id, t2.track_id) and np.array_equal(t.frame, t2.frame)


def test_gap_longer_than_max_gap_starts_a_new_track():
    rows = [(f, 1, (10 + f, 20, 20, 20)) for f in range(30) if not 10 <= f <= 19]
    t = track_table(table(rows), cfg=TrackConfig(max_gap=5, min_length=3))
    assert ids_by_truth(t) == {1: [1, 2]}
    t = track_table(table(rows), cfg=TrackConfig(max_gap=12, min_length=3))
    assert ids_by_truth(t) == {1: [1]}


def test_world_distance_tracks_small_fast_masks_iou_cannot():
    cam, ground = flat_scene()
    # two far-away 3x3 masks moving 4 px a frame: consecutive masks never overlap
    rows = [(f, k, (20 + 4 * f + 60 * (k - 1), 30, 3, 3)) for f in range(20) for k in (1, 2)]
    t = table(rows)
    xy = world_positions(t, cam, ground)
    assert np.isfinite(xy).all()
    with_world = track_table(t, cam, ground, TrackConfig(min_length=5))
    assert ids_by_truth(with_world) == {1: [1], 2: [2]}
    iou_only = track_table(t, cfg=TrackConfig(min_length=5))
    assert len(iou_only) == 0                                      # every track one frame long


def test_crossing_road_users_swap_no_identity():
    cam, ground = flat_scene()
    rows = []
    for f in range(40):
        rows.append((f, 1, (10 + 3 * f, 50, 14, 14)))
        rows.append((f, 2, (130 - 3 * f, 56, 14, 14)))
    # at the crossing the two masks overlap; the far one is hidden for 3 frames
    rows = [r for r in rows if not (r[1] == 2 and 19 <= r[0] <= 21)]
    t = track_table(table(rows), cam, ground, TrackConfig(min_length=5))
    assert ids_by_truth(t) == {1: [1], 2: [2]}


def test_track_mots_streams_two_passes(tmp_path):
    rows = [(f, 1, (10 + f, 20, 20, 20)) for f in range(12)] + [(3, 2, (100, 90, 6, 6))]
    src = table(rows)
    write_mots(tmp_path / "m.txt", src)
    n, kept = track_mots(tmp_path / "m.txt", tmp_path / "t.txt", cfg=TrackConfig(min_length=5),
                         log=lambda s: None)
    assert (n, kept) == (1, 12)
    out = read_mots(tmp_path / "t.txt")
    want = track_table(src, cfg=TrackConfig(min_length=5))
    assert np.array_equal(out.track_id, want.track_id) and out.rles == want.rles
    write_mots(tmp_path / "e.txt", [])
    assert track_mots(tmp_path / "e.txt", tmp_path / "e2.txt", log=lambda s: None) == (0, 0)


def test_frames_must_increase_and_config_is_checked():
    tr = Tracker(H, W)
    tr.update(5, [box(1, 1, 5, 5)])
    assert tr.final_ids(np.array([0, -1])).tolist() == [-1, -1]    # shorter than min_length
    with pytest.raises(InputError, match="extra.tracker.speed"):
        TrackConfig.from_dict({"speed": 3})
    with pytest.raises(InputError, match="expected an integer >= 0"):
        TrackConfig.from_dict({"max_gap": -1})


def test_score_masks_counts_switches_and_recall():
    truth = table([(f, 1, (10 + f, 20, 20, 20)) for f in range(10)])
    truth.track_id = np.full(len(truth), 7)
    est = MaskTable(truth.frame, np.where(truth.frame < 5, 1, 2), truth.class_id, H, W,
                    list(truth.rles))
    s = score_masks(truth.frames(), est.frames())
    assert (s.truth, s.matched, s.pairs, s.kept, s.switches, s.tracks) == (10, 10, 9, 8, 1, 1)
    assert s.switches_per_100 == 100.0 and s.class_accuracy([1]) == 1.0


def test_merged_blob_is_split_between_its_tracks():
    from seg2pose.structures.masks import decode

    def boxes(f):  # two road users walking side by side, 2 px apart: one blob in frames 10-14
        return [(10 + 2 * f, 40, 16, 30), (28 + 2 * f, 40, 16, 30)]

    rows, merged_rle = [], {}
    for f in range(25):
        a, b = boxes(f)
        if 10 <= f <= 14:
            m = decode(box(*a), H, W) | decode(box(*b), H, W)
            m[40:70, a[0] + 16:b[0]] = 1                        # the gap closed as well
            merged_rle[f] = encode(m)
            rows.append((f, 9, (0, 0, 1, 1)))                   # placeholder, replaced below
        else:
            rows += [(f, 1, a), (f, 2, b)]
    t = table(rows)
    for i in np.flatnonzero(t.class_id == 9):
        t.rles[i] = merged_rle[int(t.frame[i])]
        t.class_id[i] = 0
    out = track_table(t, cfg=TrackConfig(min_length=5, split_min=0.6))
    assert len(out) == 50 and sorted(set(out.track_id.tolist())) == [1, 2]
    for f in range(10, 15):
        for k, bx in enumerate(boxes(f)):
            i = np.flatnonzero((out.frame == f) & (out.track_id == k + 1))
            assert len(i) == 1
            got, want = decode(out.rles[i[0]], H, W), decode(box(*bx), H, W)
            assert (got & want).sum() / (got | want).sum() > 0.85, (f, k)
    # without splitting, one of the two loses its mask there and the ids still hold
    plain = track_table(t, cfg=TrackConfig(min_length=5, split_min=0.0))
    assert len(plain) == 45


def test_split_gives_the_overlap_to_the_road_user_in_front():
    """A pedestrian walks in front of a waiting car (its mask reaches lower in the image:
    nearer the camera) and the two come out of background subtraction as one blob in frames
    5-16. Split by the predicted masks, the pixels both could own go to the pedestrian: the
    pedestrian's part is its own box, the car's part its box less the pedestrian's."""
    from seg2pose.structures.masks import decode

    car = (60, 30, 60, 30)                                 # bottom row 59

    def ped(f):
        return (20 + 6 * f, 40, 12, 36)                    # bottom row 75: in front

    def overlaps(f):
        return ped(f)[0] + 12 > car[0] and ped(f)[0] < car[0] + car[2]

    rows, blob = [], {}
    for f in range(20):
        if overlaps(f):
            blob[f] = encode(decode(box(*car), H, W) | decode(box(*ped(f)), H, W))
            rows.append((f, 9, (0, 0, 1, 1)))              # replaced by the blob below
        else:
            rows += [(f, 1, car), (f, 2, ped(f))]
    assert sorted(blob) == list(range(5, 17))
    t = table(rows)
    for i in np.flatnonzero(t.class_id == 9):
        t.rles[i] = blob[int(t.frame[i])]
    out = track_table(t, cfg=TrackConfig(min_length=5, split_min=0.5))
    assert sorted(set(out.track_id.tolist())) == [1, 2]    # no switch, no new track
    for f in blob:
        p = decode(box(*ped(f)), H, W).astype(bool)
        want = {1: decode(box(*car), H, W).astype(bool) & ~p, 2: p}
        for k, m in want.items():
            i = np.flatnonzero((out.frame == f) & (out.track_id == k))
            assert len(i) == 1, (f, k)
            got = decode(out.rles[i[0]], H, W).astype(bool)
            assert (got & m).sum() / (got | m).sum() > 0.9, (f, k)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(-12, 12), st.integers(-4, 4))
def test_rle_columns_and_shifts_equal_dense_arrays(seed, dx, dy):
    """decode_box == the dense mask's box; shift_rles == the dense mask moved along the
    column-major pixel order by dx * H + dy (a move of dx columns and dy rows)."""
    from seg2pose.structures.masks import decode
    from seg2pose.structures.rle_runs import decode_box, shift_rles

    rng = np.random.default_rng(seed)
    h, w = 13, 11
    m = (rng.random((h, w)) < rng.uniform(0.05, 0.6)).astype(np.uint8)
    r = encode(m)
    x0 = int(rng.integers(0, w))
    x1 = int(rng.integers(x0 + 1, w + 1))
    y0 = int(rng.integers(0, h))
    y1 = int(rng.integers(y0 + 1, h + 1))
    assert (decode_box([r, r], h, x0, x1, 0, h) == m[None, :, x0:x1].astype(bool)).all()
    assert (decode_box([r, r], h, x0, x1, y0, y1) == m[None, y0:y1, x0:x1].astype(bool)).all()
    flat, k = m.T.ravel(), dx * h + dy               # |k| may exceed the image: all moved out
    want = np.zeros_like(flat)
    if 0 <= k < len(flat):
        want[k:] = flat[:len(flat) - k]
    elif -len(flat) < k < 0:
        want[:k] = flat[-k:]
    moved = shift_rles([r, r, r], [k, 0, k], [h, w])
    assert (decode(moved[0], h, w).T.ravel() == want).all() and moved[1] == r and moved[2] == moved[0]
    assert moved[0] == encode(want.reshape(w, h).T)         # the canonical RLE, byte for byte


def test_box_of_runs_takes_an_empty_background_run():
    """Runs 2 bg, 1 fg, 0 bg, 2 fg, 10 bg (not canonical: a writer may make it) fill pixels
    2-4 of a 5 x 3 image, column-major: column 0 rows 2-4."""
    from seg2pose.structures.rle_runs import box_of_runs

    got = box_of_runs([np.array([2, 1, 0, 2, 10]), np.array([15])], 5, 0, 3, 1, 5)
    want = np.zeros((5, 3), bool)
    want[2:5, 0] = True
    assert (got[0] == want[1:5]).all() and not got[1].any()
