"""Label-exact augmentation (seg2pose/training/augment.py): cuts and boundary changes, exact targets."""

import numpy as np

from seg2pose.structures.masks import decode, encode, rle_stats
from seg2pose.training.augment import AugmentConfig, augment_masks

H, W = 120, 160


def rect(x0, y0, x1, y1):
    m = np.zeros((H, W), np.uint8)
    m[y0:y1, x0:x1] = 1
    return m


def test_bottom_cut_removes_the_asked_fraction_of_rows():
    cfg = AugmentConfig(p_occlude=1.0, p_bottom=1.0, cut_min=0.5, cut_max=0.5, p_boundary=0.0)
    new, keep = augment_masks([encode(rect(40, 20, 60, 100))], H, W, np.random.default_rng(0), cfg)
    assert keep.all()
    m = decode(new[0], H, W)
    assert np.array_equal(m, rect(40, 20, 60, 60))   # 80 rows -> the top 40 stay


def test_side_cuts_and_boundary_changes():
    rng = np.random.default_rng(1)
    side = AugmentConfig(p_occlude=1.0, p_bottom=0.0, cut_min=0.25, cut_max=0.25, p_boundary=0.0)
    new, _ = augment_masks([encode(rect(40, 20, 80, 100))] * 20, H, W, rng, side)
    boxes = rle_stats(new, H, W)[2]
    lefts = {(int(b[0]), int(b[2])) for b in boxes}
    assert lefts == {(50, 80), (40, 70)}             # a quarter of 40 px from either side
    grow = AugmentConfig(p_occlude=0.0, p_boundary=1.0)
    new, keep = augment_masks([encode(rect(40, 20, 80, 100))] * 30, H, W, rng, grow)
    areas = sorted({int(a) for a in rle_stats(new, H, W)[0]})
    # erosion by a 3x3 cross: 38 x 78; dilation: 40 x 80 + one pixel row/column on each side
    assert areas == [38 * 78, 40 * 80 + 2 * 40 + 2 * 80] and keep.all()


def test_untouched_and_too_small_masks_are_not_kept():
    cfg = AugmentConfig(p_occlude=0.0, p_boundary=0.0)
    r = encode(rect(10, 10, 20, 20))
    new, keep = augment_masks([r], H, W, np.random.default_rng(0), cfg)
    assert new == [r] and not keep.any()
    tiny = AugmentConfig(p_occlude=0.0, p_boundary=1.0, min_area=1000)
    new, keep = augment_masks([r], H, W, np.random.default_rng(0), tiny)
    assert not keep.any()


def test_augmented_examples_keep_the_truth():
    """normal + target == truth for every example, augmented or not, and the augmented copies'
    targets differ from their originals' (the cut moved the normal position)."""
    import tempfile
    from pathlib import Path

    from scene_fixtures import make_tiny_scene

    from seg2pose.io.poses import read_poses
    from seg2pose.training.examples import annotated_examples

    with tempfile.TemporaryDirectory() as d:
        scene = make_tiny_scene(Path(d), frames=12, n_users=5, seed=2)
        gt = read_poses(scene.gt_path)
        plain = annotated_examples(scene, "c1", gt, "train", 420, 3)
        aug = annotated_examples(scene, "c1", gt, "train", 420, 3, augment=2,
                                 rng=np.random.default_rng(0))
    n = len(plain)
    assert n > 5 and len(aug) > 1.5 * n
    truth_plain = plain.normal + plain.target
    np.testing.assert_allclose(aug.normal[:n] + aug.target[:n], truth_plain, atol=1e-9)
    # every augmented example's truth is one of the plain examples' truths
    extra = aug.normal[n:] + aug.target[n:]
    d = np.linalg.norm(extra[:, None] - truth_plain[None], axis=2).min(axis=1)
    assert d.max() < 1e-9
    assert np.abs(aug.target[n:]).sum() > 0 and not np.allclose(aug.geo[n:], 0)
