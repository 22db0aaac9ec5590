"""Operations on masks as COCO RLE runs, without full decodes, used by the tracker
(``seg2pose.video.track``) to carry a road user's mask along while it is merged with others and to
look at only the box of a merged blob, and ``labels_to_rles``: the RLEs of a label image's
components in one pass (background subtraction's masks, a split blob's parts).

Masks are column-major COCO RLEs of an image ``h`` rows high (pycocotools' layout): runs
alternate background, foreground, starting with background; ``decode_counts`` gives the
uncompressed run lengths of many masks at once.
"""

from __future__ import annotations

import numpy as np
from pycocotools import mask as mask_util

from seg2pose.structures.masks import decode_counts


def decode_box(rles: list[bytes], h: int, x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    """(N, y1 - y0, x1 - x0) bool: the box rows y0..y1-1, columns x0..x1-1 of each mask (of an
    image ``h`` rows high), filled from the foreground runs that cross it, all masks at once."""
    vals, off = decode_counts(rles)
    return box_of_runs([vals[off[i]:off[i + 1]] for i in range(len(rles))], h, x0, x1, y0, y1)


def box_of_runs(runs: list[np.ndarray], h: int, x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    """``decode_box`` of masks given by their run lengths (uncompressed COCO RLE counts)."""
    n, bw, bh = len(runs), x1 - x0, y1 - y0
    per = np.array([len(r) for r in runs], np.int64)
    counts = np.concatenate(runs)
    owner = np.repeat(np.arange(n), per)
    first = np.repeat(np.cumsum(per) - per, per)           # each mask's first run
    cs = np.cumsum(counts)
    # positions restart at 0 for each mask: less the pixels of the masks before it
    before = np.concatenate([[0], cs[np.cumsum(per)[:-1] - 1]])
    start_all = cs - counts - np.repeat(before, per)
    fg = (np.arange(len(counts)) - first) % 2 == 1         # runs alternate background, foreground
    owner, start, length = owner[fg], start_all[fg], counts[fg]
    s = np.clip(start, x0 * h, x1 * h)
    e = np.clip(start + length, x0 * h, x1 * h)
    keep = e > s
    owner, s, e = owner[keep], s[keep], e[keep]
    c0 = s // h
    nseg = (e - 1) // h - c0 + 1                 # a run may go on into the next columns
    rep = np.repeat(np.arange(len(s)), nseg)
    col = c0[rep] + np.arange(len(rep)) - np.repeat(np.cumsum(nseg) - nseg, nseg)
    r0 = np.clip(np.maximum(s[rep] - col * h, 0), y0, y1) - y0
    r1 = np.clip(np.minimum(e[rep] - col * h, h), y0, y1) - y0
    ok = r1 > r0
    at = (owner[rep][ok] * bw + col[ok] - x0) * (bh + 1)
    # +1 where a segment starts, -1 where it ends: a cumulative sum fills them (added, not
    # set: in an RLE with an empty background run two segments touch)
    d = np.zeros((n, bw, bh + 1), np.int8)
    flat = d.reshape(-1)
    np.add.at(flat, at + r0[ok], 1)
    np.add.at(flat, at + r1[ok], -1)
    out = np.cumsum(d[:, :, :bh], axis=2, dtype=np.int8).view(bool)
    return out.transpose(0, 2, 1)


def shift_rles(rles: list[bytes], ks: list[int], size: list[int]) -> list[bytes]:
    """COCO RLEs each moved by ``ks[i]`` pixels along the column-major pixel order (k = dx * H +
    dy moves a mask dx columns right and dy rows down; pixels that a vertical move pushes past
    the bottom of a column wrap into the next one, which is negligible for prediction). The
    runs of all masks are decoded in one vectorised pass."""
    h, w = size
    all_counts, off = decode_counts(rles)
    out_rles = []
    for i, (rle, k) in enumerate(zip(rles, ks)):
        if k == 0:
            out_rles.append(rle)
            continue
        out = shift_counts(all_counts[off[i]:off[i + 1]], k, h * w).tolist()
        out_rles.append(mask_util.frPyObjects({"size": [h, w], "counts": out}, h, w)["counts"])
    return out_rles


def shift_counts(counts: np.ndarray, k: int, n: int) -> np.ndarray:
    """The run lengths (uncompressed COCO RLE) of a mask of ``n`` pixels moved by ``k`` pixels
    along the column-major order (see ``shift_rles``); a new array."""
    counts = counts.copy()
    last_bg = len(counts) % 2 == 1               # the last run is background
    if k > 0 and last_bg and counts[-1] > k:     # stays inside: only the end runs change
        counts[0] += k
        counts[-1] -= k
        return counts
    if k < 0 and counts[0] > -k:
        counts[0] += k
        return np.r_[counts[:-1], counts[-1] - k] if last_bg else np.r_[counts, -k]
    if k > 0:
        counts[0] += k
    else:                                    # cut -k pixels from the front
        ends = np.cumsum(counts)
        j = int(np.searchsorted(ends, -k, side="right"))
        counts = counts[j:]
        if len(counts):
            counts[0] = ends[j] + k
        if j % 2:                            # the first run must be background
            counts = np.r_[0, counts]
    if not len(counts):                      # moved off the image entirely
        counts = np.array([n], np.int64)
    ends = np.cumsum(counts)                 # trim to the image
    j = int(np.searchsorted(ends, n, side="left"))
    if j < len(counts):
        counts = counts[:j + 1]
        counts[-1] -= ends[j] - n
    elif len(counts) % 2:                    # the rest is background: the last run is
        counts[-1] += n - ends[-1]
    else:
        counts = np.r_[counts, n - ends[-1]]
    return counts


def labels_to_rles(labels: np.ndarray, ids: np.ndarray, x0: int = 0,
                   width: int | None = None, y0: int = 0, height: int | None = None) -> list[bytes]:
    """Compressed COCO RLEs of the components ``ids`` (K,) of a label image (H, W) int.

    One pass over the column-major pixels finds every run of equal labels; each component's
    RLE is its runs with the gaps between them, so no per-component full-image mask is made.
    ``labels`` may also be a box at column ``x0``, row ``y0`` of an image ``height`` x
    ``width`` (the rest of the image is label 0)."""
    bh, w_strip = labels.shape
    w = w_strip if width is None else int(width)
    h = bh if height is None else int(height)
    n = h * w
    flat = np.asarray(labels).T.ravel()           # column-major, as COCO RLE
    change = flat[1:] != flat[:-1]
    if bh < h:                                    # a box's columns are not contiguous
        change[bh - 1::bh] = True
    cut = np.flatnonzero(change) + 1
    vals = flat[np.r_[0, cut]]
    col, row = np.divmod(np.r_[0, cut], bh)
    starts = (x0 + col) * h + y0 + row
    col, row = np.divmod(np.r_[cut, len(flat)] - 1, bh)
    ends = (x0 + col) * h + y0 + row + 1
    out: list[bytes] = []
    if len(ids) == 0:
        return out
    order = np.argsort(vals, kind="stable")
    sv = vals[order]
    lo = np.searchsorted(sv, ids, side="left")
    hi = np.searchsorted(sv, ids, side="right")
    for k in range(len(ids)):
        sel = order[lo[k]:hi[k]]
        s, e = starts[sel], ends[sel]
        counts = np.empty(2 * len(s) + 1, np.int64)
        counts[0:-1:2] = s - np.r_[0, e[:-1]]
        counts[1::2] = e - s
        counts[-1] = n - (e[-1] if len(e) else 0)
        if counts[-1] == 0:  # pycocotools ends on the last non-empty run
            counts = counts[:-1]
        out.append(mask_util.frPyObjects({"size": [h, w], "counts": counts.tolist()}, h, w)["counts"])
    return out
