"""Masks and tracks against rendered truth: recall at an IoU, identity switches, class accuracy.

Truth and estimate are MOTS streams of one camera. Per frame, truth and estimated masks are
matched one to one by the Hungarian method on IoU, and a pair counts when IoU >= ``iou_min``
(0.5, as in MOTS). On the matched pairs:

- recall: matched truth masks / truth masks of at least ``min_area`` pixels;
- identity: for each truth track, consecutive matched frames whose estimated id is unchanged
  (``kept``), and the changes (``switches``, CLEAR-MOT's IDSW);
- classes: estimated class id == truth class id, per truth class.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from scipy.optimize import linear_sum_assignment

from seg2pose.io.mots import MaskTable
from seg2pose.structures.masks import iou, rle_stats


@dataclass
class MaskScores:
    truth: int = 0            # truth masks counted (area >= min_area)
    matched: int = 0
    estimated: int = 0        # estimated masks in the frames compared
    pairs: int = 0            # consecutive matched frames of a truth track
    kept: int = 0             # ... with the same estimated id
    switches: int = 0
    tracks: int = 0           # truth tracks with at least one match
    class_total: dict = field(default_factory=dict)   # truth class id -> matched masks
    class_right: dict = field(default_factory=dict)   # truth class id -> right class

    @property
    def recall(self) -> float:
        return self.matched / self.truth if self.truth else float("nan")

    @property
    def precision(self) -> float:
        return self.matched / self.estimated if self.estimated else float("nan")

    @property
    def identity_kept(self) -> float:
        return self.kept / self.pairs if self.pairs else float("nan")

    @property
    def switches_per_100(self) -> float:
        return 100.0 * self.switches / self.tracks if self.tracks else float("nan")

    def class_accuracy(self, ids: Iterable[int]) -> float:
        ids = list(ids)
        n = sum(self.class_total.get(i, 0) for i in ids)
        return sum(self.class_right.get(i, 0) for i in ids) / n if n else float("nan")


def score_masks(truth: Iterable[tuple[int, MaskTable]], est: Iterable[tuple[int, MaskTable]],
                iou_min: float = 0.5, min_area: int = 150) -> MaskScores:
    """Compare two frame-ordered streams of one camera (see the module docstring)."""
    s = MaskScores()
    est_it = iter(est)
    cur = next(est_it, None)
    last_id: dict[int, int] = {}
    for f, tt in truth:
        while cur is not None and cur[0] < f:
            cur = next(est_it, None)
        ee = cur[1] if cur is not None and cur[0] == f else None
        area, _, _ = rle_stats(tt.rles, tt.height, tt.width)
        big = area >= min_area
        s.truth += int(big.sum())
        if ee is None or len(ee) == 0:
            continue
        s.estimated += len(ee)
        m = iou(tt.rles, ee.rles, tt.height, tt.width)
        r, c = linear_sum_assignment(-m)
        ok = m[r, c] >= iou_min
        r, c = r[ok], c[ok]
        s.matched += int(big[r].sum())
        for i, j in zip(r, c):
            tid, eid, cls = int(tt.track_id[i]), int(ee.track_id[j]), int(tt.class_id[i])
            s.class_total[cls] = s.class_total.get(cls, 0) + 1
            s.class_right[cls] = s.class_right.get(cls, 0) + int(ee.class_id[j] == cls)
            if tid in last_id:
                s.pairs += 1
                if last_id[tid] == eid:
                    s.kept += 1
                else:
                    s.switches += 1
            else:
                s.tracks += 1
            last_id[tid] = eid
    return s
