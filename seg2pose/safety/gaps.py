"""Missing frames and impossible jumps in road-user tracks.

A tracker loses a road user for a few frames (occlusion, a missed mask): the short gaps are
filled by interpolating linearly between the frames on either side (the position; the
heading along the shorter arc; r90 as the larger of the two), so that TTC and PET are
computed at every frame and the smoother's windows do not reach over a hole. A long gap
(more than ``max_gap_s``) is left open: the track is two segments there, each smoothed on its
own, and the analysis says how many there were.

A track that moves farther between two of its rows than its class can move in that time
(``MAX_SPEED_MPS``) is two road users under one id (a tracker's id switch, or a reused id):
``jumps`` finds them so that readers can warn.
"""

from __future__ import annotations

import numpy as np

from seg2pose.safety.tracks import Tracks

# the fastest a road user of the class moves, m/s (urban traffic with a margin: a car at
# 130 km/h, a bicyclist at 54 km/h, a running pedestrian at 36 km/h)
MAX_SPEED_MPS = {"car": 36.0, "truck": 36.0, "bus": 36.0, "motorcycle": 45.0, "moped": 20.0,
                 "bicyclist": 15.0, "pedestrian": 10.0}
DEFAULT_MAX_SPEED_MPS = 45.0


def fill_gaps(tracks: Tracks, max_gap_s: float) -> tuple[Tracks, np.ndarray, dict]:
    """``tracks`` with the missing frames of gaps up to ``max_gap_s`` seconds (the time
    between the two rows around it) filled in; (N',) bool, which rows were filled in; and
    counts {"filled": gaps filled, "frames": rows added, "open": gaps left open}."""
    f, tid = tracks.frame, tracks.track_id
    same = tid[1:] == tid[:-1]
    step = np.diff(f)
    gap = same & (step > 1)
    fill = gap & (step <= max_gap_s * tracks.fps + 1e-9)
    stats = {"filled": int(fill.sum()), "frames": int((step[fill] - 1).sum()),
             "open": int((gap & ~fill).sum())}
    if not fill.any():
        return tracks, np.zeros(len(tracks), bool), stats
    i = np.flatnonzero(fill)  # rows i and i + 1 around each gap
    k = step[i] - 1
    owner = np.repeat(i, k)
    j = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k) + 1  # 1 .. k
    a = (j / np.repeat(step[i], k))[:, None]  # share of the way from row i to i + 1
    xy = tracks.xy[owner] * (1 - a) + tracks.xy[owner + 1] * a
    h0, h1 = tracks.heading[owner], tracks.heading[owner + 1]
    turn = np.angle(np.exp(1j * (h1 - h0)))
    heading = np.where(np.isfinite(h0) & np.isfinite(h1), h0 + turn * a[:, 0], np.nan)
    r90 = None
    if tracks.r90 is not None:
        r90 = np.r_[tracks.r90, np.fmax(tracks.r90[owner], tracks.r90[owner + 1])]
    out = Tracks(np.r_[f, f[owner] + j], np.r_[tid, tid[owner]], np.r_[tracks.cls, tracks.cls[owner]],
                 np.r_[tracks.xy, xy], np.r_[tracks.heading, heading],
                 np.r_[tracks.size, tracks.size[owner]], tracks.fps, r90)
    # Tracks sorts by (track, frame): the added rows are the ones whose frame is not a
    # frame of the track in the input
    added = np.r_[np.zeros(len(tracks), bool), np.ones(len(owner), bool)]
    order = np.lexsort((np.r_[f, f[owner] + j], np.r_[tid, tid[owner]]))
    return out, added[order], stats


def jumps(tracks: Tracks) -> np.ndarray:
    """(J,) rows that lie farther from their track's previous row than the class's top speed
    (``MAX_SPEED_MPS``, plus one footprint length for the pose's error) allows in the time
    between them."""
    if len(tracks) < 2:
        return np.zeros(0, np.int64)
    same = tracks.track_id[1:] == tracks.track_id[:-1]
    dt = np.diff(tracks.frame) / tracks.fps
    d = np.hypot(*np.diff(tracks.xy, axis=0).T)
    vmax = _class_speeds(tracks.cls[1:])
    bad = same & (d > vmax * dt + tracks.size[1:, 0])
    return np.flatnonzero(bad) + 1


def _class_speeds(cls: np.ndarray) -> np.ndarray:
    """(N,) MAX_SPEED_MPS per row, looked up once per run of equal names."""
    heads = np.flatnonzero(np.r_[True, cls[1:] != cls[:-1]])
    v = np.array([MAX_SPEED_MPS.get(str(c).lower(), DEFAULT_MAX_SPEED_MPS) for c in cls[heads]])
    return np.repeat(v, np.diff(np.r_[heads, len(cls)]))


def jump_note(tracks: Tracks, rows: np.ndarray, limit: int = 5) -> str:
    """One line naming the tracks that jump (at most ``limit`` of them, with frame and metres)."""
    parts = []
    for r in rows[:limit]:
        d = float(np.hypot(*(tracks.xy[r] - tracks.xy[r - 1])))
        parts.append(f"track {int(tracks.track_id[r])} ({tracks.cls[r]}) {d:.0f} m between frames "
                     f"{int(tracks.frame[r - 1])} and {int(tracks.frame[r])}")
    more = f" and {len(rows) - limit} more" if len(rows) > limit else ""
    return (f"{len(rows)} jumps farther than the class can move: " + "; ".join(parts) + more
            + " (two road users under one id? each is analysed as one road user)")
