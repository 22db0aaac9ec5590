"""Masks: RLE decoding, centres and boxes straight from RLE equal those of decoded masks."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.core.errors import InputError
from seg2pose.structures.masks import (
    crop_masks,
    decode,
    decode_counts,
    encode,
    iou,
    mask_centers,
    merge_bicyclists,
    rle_stats,
)


def runs_of(mask: np.ndarray) -> list[int]:
    """Column-major run lengths starting with background, as COCO defines them."""
    flat = mask.flatten(order="F").astype(np.int8)
    out, cur, n = [], 0, 0
    for v in flat:  # plain loop: the reference is meant to be obviously right
        if v == cur:
            n += 1
        else:
            out.append(n)
            cur, n = v, 1
    out.append(n)
    return out


def random_masks(seed: int, n: int, h: int, w: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    masks = []
    for k in range(n):
        m = np.zeros((h, w), np.uint8)
        kind = k % 4
        if kind == 0:  # blob
            c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            cv2.ellipse(m, c, (int(rng.integers(1, w + 1)), int(rng.integers(1, h + 1))),
                        float(rng.uniform(0, 180)), 0, 360, 1, -1)
        elif kind == 1:  # noise
            m[:] = rng.random((h, w)) < rng.uniform(0, 1)
        elif kind == 2:  # full or empty
            m[:] = int(rng.integers(0, 2))
        else:  # single pixel
            m[int(rng.integers(0, h)), int(rng.integers(0, w))] = 1
        masks.append(m)
    return masks


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 40), st.integers(1, 40))
def test_rle_decoding_and_stats_match_decoded_masks(seed, h, w):
    masks = random_masks(seed, 8, h, w)
    rles = [encode(m) for m in masks]
    counts, offsets = decode_counts(rles)
    for i, m in enumerate(masks):
        assert counts[offsets[i]:offsets[i + 1]].tolist() == runs_of(m)
        assert np.array_equal(decode(rles[i], h, w), m)
    area, cen, box = rle_stats(rles, h, w)
    for i, m in enumerate(masks):
        ys, xs = np.nonzero(m)
        assert area[i] == len(xs)
        if len(xs) == 0:
            assert np.isnan(cen[i]).all() and np.isnan(box[i]).all()
            continue
        assert np.allclose(cen[i], [xs.mean() + 0.5, ys.mean() + 0.5], atol=1e-9)
        assert box[i].tolist() == [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
    bc = mask_centers(rles, h, w, "bbox")
    cc = mask_centers(rles, h, w, "centroid")
    ok = area > 0
    assert np.allclose(bc[ok], np.stack([(box[ok, 0] + box[ok, 2]) / 2, (box[ok, 1] + box[ok, 3]) / 2], 1))
    assert np.allclose(cc[ok], cen[ok])


def test_centres_by_hand():
    m = np.zeros((10, 20), np.uint8)
    m[2:4, 5:9] = 1  # rows 2-3, cols 5-8: box [5, 9) x [2, 4)
    m[7, 5] = 1      # an extra pixel making the centroid differ from the box centre
    r = [encode(m)]
    assert mask_centers(r, 10, 20, "bbox").tolist() == [[7.0, 5.0]]
    cx = (2 * (5.5 + 6.5 + 7.5 + 8.5) + 5.5) / 9
    cy = (4 * 2.5 + 4 * 3.5 + 7.5) / 9
    assert np.allclose(mask_centers(r, 10, 20, "centroid"), [[cx, cy]])
    with pytest.raises(InputError, match="unknown centre"):
        mask_centers(r, 10, 20, "median")


def test_bad_rle_strings():
    with pytest.raises(InputError, match="alphabet"):
        decode_counts([b"0 0"])
    with pytest.raises(InputError, match="truncated"):
        decode_counts([b"1o"])  # 'o' = 0x3f: 'more follows' at the end of the string
    assert decode_counts([])[0].size == 0


def test_crop_masks_padding_and_placement():
    h, w = 50, 60
    m = np.zeros((h, w), np.uint8)
    m[0:3, 0:2] = 1  # in the top-left corner
    crops = crop_masks([encode(m)], h, w, np.array([[1.0, 1.5]]), size=10)
    # crop origin = round(centre - 5) = (-4, -4): the mask lands at rows/cols 4..
    want = np.zeros((10, 10), np.uint8)
    want[4:7, 4:6] = 1
    assert np.array_equal(crops[0], want)
    # many masks, decoded in chunks, each placed at its own centre
    rng = np.random.default_rng(0)
    masks = random_masks(3, 150, h, w)
    cen = rng.uniform(0, [w, h], (150, 2))
    crops = crop_masks([encode(x) for x in masks], h, w, cen, size=20)
    for i in (0, 77, 149):
        x0, y0 = np.round(cen[i] - 10).astype(int)
        pad = np.zeros((h + 40, w + 40), np.uint8)
        pad[20:20 + h, 20:20 + w] = masks[i]
        assert np.array_equal(crops[i], pad[y0 + 20:y0 + 40, x0 + 20:x0 + 40])


def test_iou_and_bicyclist_merge():
    h, w = 20, 20
    person = np.zeros((h, w), np.uint8)
    person[2:10, 5:8] = 1  # 24 px
    bike = np.zeros((h, w), np.uint8)
    bike[8:14, 3:11] = 1  # 48 px, overlap rows 8-9 x cols 5-7 = 6 px
    walker = np.zeros((h, w), np.uint8)
    walker[15:19, 15:17] = 1
    P, B = [encode(person), encode(walker)], [encode(bike)]
    assert iou(P, B, h, w)[0, 0] == pytest.approx(6 / (24 + 48 - 6))
    merged, match = merge_bicyclists(P, B, h, w, min_overlap=0.05)
    assert match.tolist() == [0, -1]
    assert np.array_equal(decode(merged[0], h, w), person | bike)


def test_rle_stats_in_chunks_equals_one_block(monkeypatch):
    import seg2pose.structures.masks as M

    rles = [encode(m) for m in random_masks(5, 11, 17, 23)]
    want = M.rle_stats(rles, 17, 23)
    monkeypatch.setattr(M, "_STATS_CHUNK", 3)
    got = M.rle_stats(rles, 17, 23)
    for a, b in zip(got, want):
        assert np.array_equal(a, b, equal_nan=True)
