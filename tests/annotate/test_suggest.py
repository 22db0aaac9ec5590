"""The queue of what to annotate next (annotate.suggest): gains computed by hand, the greedy
turn to uncovered classes and distances, annotated road users left out, frames spread."""

from __future__ import annotations

import numpy as np

from annotate.suggest import FLOOR, annotation_queue, spread_frames
from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable


def _views(rows):
    """rows: (track, class, camera, frames, x, y, residual length along x)."""
    cols = {k: [] for k in ("f", "t", "cam", "cls", "x", "y", "r")}
    for tid, cls, cam, frames, x, y, r in rows:
        for f in frames:
            cols["f"].append(f)
            cols["t"].append(tid)
            cols["cam"].append(cam)
            cols["cls"].append(cls)
            cols["x"].append(x)
            cols["y"].append(y)
            cols["r"].append(r)
    n = len(cols["f"])
    normal = np.column_stack([cols["x"], cols["y"], np.zeros(n)])
    return ViewTable(np.array(cols["f"]), np.array(cols["t"]), np.array(cols["cam"], object),
                     np.array(cols["cls"], object), np.zeros((n, 2)), normal,
                     np.column_stack([cols["r"], np.zeros(n)]))


def _no_poses():
    return PoseTable(np.zeros(0), np.zeros(0), np.zeros(0, object), np.zeros((0, 3)), np.zeros(0))


F = range(50)


def test_gain_by_hand_and_the_greedy_turn_to_another_class():
    """A: car, the model moves it 1.0 m; B: car, 0.2 m; C: pedestrian, 0.2 m; all 50 frames,
    20 m from the cameras (one distance bin), residuals measured from x = 20 - r. Gains:
    A (1.0 + 0.1) sqrt(50) = 7.78 first; then C 0.3 sqrt(50) = 2.12 (no pedestrian yet) before
    B 0.3 sqrt(50) / ((1 + 1) (1 + 1)) = 0.53 (one car, in its bin, queued already)."""
    v = _views([(1, "car", "c0", F, 19.0, 0.0, 1.0), (2, "car", "c0", F, 19.8, 0.5, 0.2),
                (3, "pedestrian", "c0", F, 19.8, -0.5, 0.2)])
    q = annotation_queue(v, _no_poses(), np.zeros(2))
    assert [c.track for c in q] == [1, 3, 2]
    s50 = np.sqrt(50)
    np.testing.assert_allclose([c.gain for c in q],
                               [(1.0 + FLOOR) * s50, (0.2 + FLOOR) * s50, (0.2 + FLOOR) * s50 / 4])
    assert "no car annotated yet" in q[0].why and "no pedestrian annotated yet" in q[1].why
    assert q[0].frames == (0, 12, 24, 37, 49) and q[0].cls == "car"


def test_annotated_road_users_are_left_out_and_count_as_coverage():
    """Track 1 has an annotated track 1 m beside it in every frame: left out, and the
    pedestrian it is makes track 2 (a pedestrian) count half."""
    v = _views([(1, "pedestrian", "c0", F, 20.0, 0.0, 0.0), (2, "pedestrian", "c0", F, 40.0, 0.0, 0.0)])
    n = len(F)
    ann = PoseTable(np.array(F), np.full(n, 7), np.full(n, "pedestrian", object),
                    np.column_stack([np.full(n, 21.0), np.zeros(n), np.zeros(n)]), np.zeros(n))
    q = annotation_queue(v, ann, np.zeros(2))
    assert [c.track for c in q] == [2]
    np.testing.assert_allclose(q[0].gain, FLOOR * np.sqrt(50) / 2)  # (1 + 1 pedestrian) x (1 + 0 at 40 m)


def test_lenses_that_disagree_count_their_spread():
    """Two lenses 0.4 m apart in every frame: each is 0.2 m from the frame's mean, so the
    lenses' disagreement is 0.4 m; the gain is (0.4 + 0.1) sqrt(frames)."""
    v = _views([(1, "car", "c0", F, 20.0, 0.0, 0.0), (1, "car", "c1", F, 20.4, 0.0, 0.0)])
    q = annotation_queue(v, _no_poses(), np.zeros(2))
    np.testing.assert_allclose(q[0].gain, (0.4 + FLOOR) * np.sqrt(50))
    assert "lenses 0.40 m apart" in q[0].why


def test_frames_outside_the_range_and_short_tracks_are_not_suggested():
    v = _views([(1, "car", "c0", range(0, 2), 20.0, 0.0, 0.5), (2, "car", "c0", range(0, 40), 20.0, 5.0, 0.5)])
    q = annotation_queue(v, _no_poses(), np.zeros(2), frames=(10, 19))
    assert [c.track for c in q] == [2] and q[0].frames == (10, 12, 14, 17, 19)
    assert spread_frames(np.array([3, 8]), 5) == (3, 8)


def test_a_road_user_with_merged_or_cut_masks_counts_for_less():
    """Two cars alike but for their masks: car 2's box doubles in area in 20 of its 50 frames
    (merged with a neighbour) and is cut by the border in 5 more: its mask quality is
    (50 - 25) / 50 = 0.5 and so is its gain against car 1's (whole masks, quality 1)."""
    from annotate.suggest import mask_quality

    v = _views([(1, "car", "c0", F, 19.0, 0.0, 1.0), (2, "car", "c0", F, 19.0, 0.5, 1.0)])
    n = len(v.frame)
    box = np.tile([100.0, 100.0, 140.0, 130.0], (n, 1))  # 40 x 30 px
    cues = np.zeros((n, 3))
    car2 = np.flatnonzero(v.track_id == 2)
    box[car2[:20], 2] = 180.0          # 80 x 30: twice the median area
    cues[car2[20:25], 0] = 1           # cut by the image border
    v = ViewTable(v.frame, v.track_id, v.camera, v.cls, v.uv, v.normal, v.residual, cues=cues, box=box)
    assert mask_quality(v, np.flatnonzero(v.track_id == 1)) == 1.0
    assert mask_quality(v, car2) == 0.5
    q = annotation_queue(v, _no_poses(), np.zeros(2))
    gains = {c.track: c.gain for c in q}
    assert q[0].track == 1 and "masks whole" not in q[0].why and "masks whole in 50 %" in q[1].why
    # car 2 is the second car in the same 10 m bin: its gain is also divided by (1+1)(1+1)
    np.testing.assert_allclose(gains[2], gains[1] * 0.5 / 4)
