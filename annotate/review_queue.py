"""The review workflow's engine: which frames still need a look (across all tracks, ordered by
the error expected there) and where a playback of a track should stop.

A frame needs a look when its row is an unchecked estimate (``estimate-unchecked``: a
pre-annotation or estimates taken every N frames, in no reviewed span). Its expected error
is the larger of the run estimate's error bar there (``r90_m`` of the run, when the track is
linked to a run track) and the distance between the track and its road user's reference: the
run's estimates when a run is loaded (they exist only where its masks are), else the masks'
normal positions (``annotate.review.distance_series``). Consecutive such frames of a track form
one ``Look``, at its worst frame.

Playback stops (``play_stop``) at the first frame after the start where the track leaves its
road user (farther than ``STOP_DISTANCE`` from the reference), where the plausibility
rules flag it (``annotate.review.plausibility_report``), where its rows end (an outside span)
or at the track's last row.

    from annotate.review_queue import review_queue, play_stop
    for look in review_queue(project)[:5]:
        print(look.track, look.frame, f"{look.score:.2f} m", look.first, look.last)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from annotate.review import distance_series, plausibility_report
from annotate.table import UNCHECKED

STOP_DISTANCE = 1.0   # metres from the masks' normal positions: playback stops there
NO_REFERENCE = 0.0    # the score of a frame without a normal position or an error bar


@dataclass(frozen=True)
class Look:
    """Frames first..last of ``track`` that need a look; ``frame``: the worst one, ``score``
    its expected error (metres)."""

    track: int
    frame: int
    score: float
    first: int
    last: int


def _r90(project, track: int, frames: np.ndarray) -> np.ndarray:
    """The run estimate's r90 (F,) metres at ``frames`` of a track linked to a run track
    (NaN where unknown)."""
    out = np.full(len(frames), np.nan)
    run = getattr(project, "_run", None)
    rt = project.track(track).meta.get("run_track")
    if run is None or rt is None or run.table.r90 is None:
        return out
    est = run.track(int(rt))
    k = np.searchsorted(est.frame, frames)
    ok = (k < len(est.frame)) & (est.frame[np.minimum(k, len(est.frame) - 1)] == frames)
    out[ok] = est.r90[k[ok]]
    return out


def reference_source(project) -> str:
    """The reference a track is checked against: "estimate" (a run is loaded) or "normal"."""
    return "estimate" if getattr(project, "_run", None) is not None else "normal"


def review_queue(project, ref=None, tracks=None) -> list[Look]:
    """Every stretch of frames that needs a look, worst first (module docstring). ref:
    ``annotate.review.reference(project, reference_source(project))`` when at hand (the masks'
    normal positions take a while on a large scene)."""
    from annotate.review import reference

    source = reference_source(project)
    ids = sorted(project.tracks) if tracks is None else [int(t) for t in tracks]
    out = []
    for tid in ids:
        rows = project.track_poses(tid)
        need = rows.source == UNCHECKED
        if not need.any():
            continue
        if ref is None:
            ref = reference(project, source)
        _, dist = distance_series(project, tid, source, ref=ref)
        score = np.fmax(np.nan_to_num(dist, nan=NO_REFERENCE), np.nan_to_num(
            _r90(project, tid, rows.frame), nan=NO_REFERENCE))
        idx = np.flatnonzero(need)
        cut = np.flatnonzero(np.diff(rows.frame[idx]) != 1) + 1
        for g in np.split(idx, cut):
            worst = g[int(np.argmax(score[g]))]
            out.append(Look(tid, int(rows.frame[worst]), float(score[worst]),
                            int(rows.frame[g[0]]), int(rows.frame[g[-1]])))
    out.sort(key=lambda lk: (-lk.score, lk.track, lk.frame))
    return out


def play_stop(project, track: int, start: int, ref=None, stop_distance: float = STOP_DISTANCE
              ) -> tuple[int, str]:
    """(frame, why) where a playback of ``track`` from ``start`` stops (module docstring)."""
    from annotate.review import reference

    rows = project.track_poses(track)
    later = np.flatnonzero(rows.frame > start)
    if not len(later):
        return int(start), "the end of the track"
    source = reference_source(project)
    if ref is None:
        ref = reference(project, source)
    _, dist = distance_series(project, track, source, ref=ref)
    issues = [i for i in plausibility_report(project) if i.track == track
              and i.kind != "gap" and i.last > start]
    prev = int(start) if int(start) in set(rows.frame.tolist()) else int(rows.frame[later[0]]) - 1
    for i in later:
        f = int(rows.frame[i])
        if f != prev + 1:
            return prev, f"the track has no pose from frame {prev + 1} (outside)"
        if np.isfinite(dist[i]) and dist[i] > stop_distance:
            return f, (f"the track is {dist[i]:.2f} m from its road user's "
                       f"{'estimate' if source == 'estimate' else 'masks'}")
        for iss in issues:
            if iss.first <= f <= iss.last:
                return f, iss.message
        prev = f
    return prev, "the end of the track"
