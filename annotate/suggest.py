"""What to annotate next, across the scene: road users (the run's tracks) ranked by how much a
few keyframes on them are expected to teach Seg2PoseNet, as a queue the app shows and walks.

    from annotate.suggest import annotation_queue
    for c in annotation_queue(read_views(run / "views.csv"), project.poses(), scene.rig.center[:2])[:5]:
        print(c.track, c.frames, f"{c.gain:.2f}", c.why)

Expected gain of a road user (a heuristic; measured against a uniform choice in
benches/annotation_curve.py, docs/RESULTS.md):

- **uncertainty** (metres): what the start model is unsure or likely wrong about -- the mean
  error bar ``r90_m`` of its views (0 where the run has no calibration), how far the model moves
  the views from their normal positions (the start model disagrees with the baseline: where it
  is wrong, it is wrong by about that much, docs/RESULTS.md "Error budget"), and how far the
  lenses' estimates of one frame lie apart; plus ``FLOOR`` so that a calm road user still counts;
- **mask quality** (0-1): the share of its views whose mask looks like one whole road user --
  box area within ``AREA_RATIO`` of the track's median and not cut by the image border. A
  merged pair of cars or a bus cut in two moves the start model far from the baseline (a high
  uncertainty above), yet its frames teach little: matched to one annotated road user, such a
  mask's example is wrong or dropped (residuals beyond 2.5 m). 1 where the run has no boxes;
- **examples**: the square root of the frames it is seen in (capped at ``MAX_FRAMES``): a long
  track gives many interpolated examples and many positions from the same keyframes;
- **coverage**: divided by (1 + road users of its class annotated or queued before it) and by
  (1 + those also within its ``DISTANCE_BIN`` of distance from the cameras): the queue turns to
  classes and distances the annotations do not cover yet.

The queue is greedy: after each pick the coverage counts include it. Road users already
annotated (an annotated track within ``GATE`` metres of the run's estimate in at least
``COVERED_SHARE`` of its frames) are left out. Each entry carries ``per_track`` frames spread over
the frames the road user is seen in (first and last included), where keyframes make the
interpolation span it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.io.poses import PoseTable
from seg2pose.io.run import ViewTable

FLOOR = 0.1            # metres added to every road user's uncertainty
MAX_FRAMES = 100       # frames seen beyond this add no weight
DISTANCE_BIN = 10.0    # metres: the coverage of distances from the cameras
GATE = 3.0             # metres: an annotated pose this close to an estimate is the same road user
COVERED_SHARE = 0.3    # of a road user's frames with such a pose: annotated already
MIN_FRAMES = 3         # road users seen in fewer frames are not suggested
AREA_RATIO = 1.5       # a view's box area beyond this factor of its track's median: a bad mask


@dataclass(frozen=True)
class Candidate:
    """A road user worth annotating: the run's ``track`` id, its class, the ``frames`` to put
    keyframes at (spread over where it is seen), ``gain`` (the score above, larger first) and
    ``why`` (one line for the panel)."""

    track: int
    cls: str
    frames: tuple[int, ...]
    gain: float
    distance_m: float
    why: str


@dataclass(frozen=True)
class _Track:
    track: int
    cls: str
    frames: np.ndarray
    r90: float
    moved: float
    lenses: float
    distance: float
    xy: np.ndarray     # (n, 2) the track's estimate per frame of ``frames`` (mean over lenses)
    quality: float = 1.0  # share of its views with a whole-looking mask (module docstring)


def _tracks(views: ViewTable, center_xy: np.ndarray, frames: tuple[int, int] | None) -> list[_Track]:
    ok = (views.track_id >= 0) & np.isfinite(views.normal[:, :2]).all(axis=1)
    if frames is not None:
        ok &= (views.frame >= frames[0]) & (views.frame <= frames[1])
    idx = np.flatnonzero(ok)
    est = views.normal[idx, :2] + views.residual[idx]
    moved = np.linalg.norm(views.residual[idx], axis=1)
    r90 = views.r90[idx] if views.r90 is not None else np.full(len(idx), np.nan)
    out = []
    tid = views.track_id[idx]
    for t in np.unique(tid):
        sel = np.flatnonzero(tid == t)
        fr = views.frame[idx[sel]]
        uf, inv = np.unique(fr, return_inverse=True)
        if len(uf) < MIN_FRAMES:
            continue
        xy = np.zeros((len(uf), 2))
        np.add.at(xy, inv, est[sel])
        count = np.bincount(inv, minlength=len(uf))
        xy /= count[:, None]
        spread = np.linalg.norm(est[sel] - xy[inv], axis=1)  # each lens from the frame's mean
        multi = count[inv] > 1
        lenses = float(2 * spread[multi].mean()) if multi.any() else 0.0
        cls_vals, cls_n = np.unique(views.cls[idx[sel]].astype(str), return_counts=True)
        fin = r90[sel][np.isfinite(r90[sel])]
        out.append(_Track(int(t), str(cls_vals[np.argmax(cls_n)]), uf,
                          float(fin.mean()) if len(fin) else 0.0, float(moved[sel].mean()), lenses,
                          float(np.median(np.linalg.norm(xy - center_xy[:2], axis=1))), xy,
                          mask_quality(views, idx[sel])))
    return out


def mask_quality(views: ViewTable, rows: np.ndarray) -> float:
    """The share of the views ``rows`` (one road user's) whose box area lies within
    ``AREA_RATIO`` of their median and whose mask is not cut by the image border (cues[:, 0]);
    1.0 when the views have no boxes."""
    if views.box is None or not len(rows):
        return 1.0
    b = views.box[rows]
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    ok = np.isfinite(area) & (area > 0)
    if not ok.any():
        return 0.0
    med = float(np.median(area[ok]))
    with np.errstate(divide="ignore", invalid="ignore"):
        whole = ok & (area <= AREA_RATIO * med) & (area >= med / AREA_RATIO)
    if views.cues is not None:
        whole &= views.cues[rows, 0] == 0
    return float(whole.mean())


def _covered(t: _Track, annotated: PoseTable) -> bool:
    """Whether an annotated track follows ``t`` (within GATE in COVERED_SHARE of its frames)."""
    if not len(annotated):
        return False
    hit = 0
    order = np.argsort(annotated.frame, kind="stable")
    af, axy = annotated.frame[order], annotated.xyz[order, :2]
    lo = np.searchsorted(af, t.frames, side="left")
    hi = np.searchsorted(af, t.frames, side="right")
    for k in range(len(t.frames)):
        if hi[k] > lo[k] and np.min(np.linalg.norm(axy[lo[k]:hi[k]] - t.xy[k], axis=1)) <= GATE:
            hit += 1
    return hit >= COVERED_SHARE * len(t.frames)


def spread_frames(frames: np.ndarray, k: int) -> tuple[int, ...]:
    """``k`` of the sorted ``frames`` evenly spread, first and last included (all when fewer)."""
    if len(frames) <= k:
        return tuple(int(f) for f in frames)
    pick = np.unique(np.round(np.linspace(0, len(frames) - 1, k)).astype(int))
    return tuple(int(frames[i]) for i in pick)


def annotation_queue(views: ViewTable, annotated: PoseTable, center_xy, frames: tuple[int, int] | None = None,
                     per_track: int = 5, limit: int = 30) -> list[Candidate]:
    """The queue of road users to annotate next (module docstring), best first: ``views`` of a
    run of the start model (RUN/views.csv), the ``annotated`` poses so far (the project's
    ``poses()``), the cameras' centre (2,) metres; only frames in ``frames`` (first, last)
    when given (e.g. not the test split)."""
    center_xy = np.asarray(center_xy, float)
    tracks = [t for t in _tracks(views, center_xy, frames) if not _covered(t, annotated)]
    n_cls: dict[str, int] = {}
    n_bin: dict[tuple[str, int], int] = {}
    for t in np.unique(annotated.track_id) if len(annotated) else []:
        rows = np.flatnonzero(annotated.track_id == t)
        c = str(annotated.cls[rows[0]])
        d = float(np.median(np.linalg.norm(annotated.xyz[rows, :2] - center_xy[:2], axis=1)))
        n_cls[c] = n_cls.get(c, 0) + 1
        n_bin[(c, int(d // DISTANCE_BIN))] = n_bin.get((c, int(d // DISTANCE_BIN)), 0) + 1
    base = {t.track: (t.r90 + t.moved + t.lenses + FLOOR) * t.quality
            * np.sqrt(min(len(t.frames), MAX_FRAMES)) for t in tracks}
    queue: list[Candidate] = []
    left = list(tracks)
    while left and len(queue) < limit:
        def gain(t: _Track) -> float:
            b = (t.cls, int(t.distance // DISTANCE_BIN))
            return base[t.track] / ((1 + n_cls.get(t.cls, 0)) * (1 + n_bin.get(b, 0)))

        best = max(left, key=lambda t: (gain(t), -t.track))
        left.remove(best)
        b = (best.cls, int(best.distance // DISTANCE_BIN))
        news = ("no " + best.cls + " annotated yet" if not n_cls.get(best.cls) else
                f"no {best.cls} at {b[1] * DISTANCE_BIN:.0f}-{(b[1] + 1) * DISTANCE_BIN:.0f} m yet"
                if not n_bin.get(b) else f"{n_cls[best.cls]} {best.cls}(s) annotated")
        why = (f"{best.cls} at {best.distance:.0f} m, seen in {len(best.frames)} frames; the model moves "
               f"it {best.moved:.2f} m from the baseline"
               + (f", error bar {best.r90:.2f} m" if best.r90 else "")
               + (f", lenses {best.lenses:.2f} m apart" if best.lenses else "")
               + (f", masks whole in {100 * best.quality:.0f} %" if best.quality < 1 else "")
               + f"; {news}")
        queue.append(Candidate(best.track, best.cls, spread_frames(best.frames, per_track),
                               float(gain(best)), best.distance, why))
        n_cls[best.cls] = n_cls.get(best.cls, 0) + 1
        n_bin[b] = n_bin.get(b, 0) + 1
    return queue


def project_queue(project, per_track: int = 5, limit: int = 30) -> list[Candidate]:
    """``annotation_queue`` of an open project with a run loaded (its views.csv), outside the
    scene's test split (held out for measuring); [] without a run or its views."""
    from seg2pose.io.run import read_views

    run = getattr(project, "_run", None)
    if run is None or not (run.path / "views.csv").exists():
        return []
    scene = project.scene
    views = read_views(run.path / "views.csv")
    if "test" in scene.splits:
        a, b = scene.split_range("test")
        views = views.take(np.flatnonzero((views.frame < a) | (views.frame > b)))
    return annotation_queue(views, project.poses(), scene.rig.center[:2], None, per_track, limit)
