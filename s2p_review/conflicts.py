"""Traffic conflicts in a review recording and an MCAP export (``s2p review --conflicts``,
``s2p export --conflicts``), from a ``conflicts.csv`` written by ``s2p conflicts``.

Entities (``layout``'s naming)::

    conflicts/events                    TextLog: one line per conflict at its frame (the time
                                        panel shows a tick per event: the timeline's markers)
    conflicts/ttc/c<k>                  Scalars: the pair's TTC per frame (s), over the encounter
    conflicts/distance/c<k>             Scalars: the pair's centre distance per frame (m)
    world/conflicts/c<k>/now            LineStrips3D: both footprints at the min-TTC frame (red)
    world/conflicts/c<k>/predicted      LineStrips3D: their predicted paths and footprints at
                                        the moment of collision (min-TTC frame + TTC)
    world/conflicts/c<k>/pet            LineStrips3D: the first road user's footprint as it
                                        leaves the shared spot and the second's as it enters
                                        (yellow), from the PET entry frame
    world/conflicts/map                 Points3D (static): the conflict map, each conflict's
                                        predicted point of contact at its minimum TTC
    conflicts/tct                       Points2D and LineStrips2D (static): the TCT chart, each
                                        conflict's (TA s, conflicting speed km/h) with its TA
                                        interval, and the serious / slight boundary

The highlights stay for ``HOLD_S`` seconds from their frame (then cleared); the plots cover
the ``BEFORE_S`` seconds before the conflict's frame to ``HOLD_S`` after it, so that a
recording with many conflicts stays readable. The camera views show both road users as every
road user (their boxes projected).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from s2p_review import layout as L
from s2p_review.columns import send_scalars
from seg2pose.core.errors import InputError
from seg2pose.io.poses import PoseTable
from seg2pose.io.text import read_text

EVENTS = "conflicts/events"
TOPIC = "/s2p/conflicts"
REQUIRED = ["track_a", "class_a", "track_b", "class_b", "type", "conflict", "first_frame",
            "last_frame", "min_ttc_s", "min_ttc_frame", "pet_s", "pet_first_track",
            "pet_exit_frame", "pet_enter_frame"]
TEXT = {"class_a", "class_b", "type", "ssam_type", "evasive_kind", "tct_severity"}
RED, ORANGE, YELLOW = (255, 40, 40), (255, 150, 40), (255, 230, 40)
BEFORE_S, HOLD_S = 3.0, 1.0
SCHEMA = {"title": "s2p.Conflict", "type": "object",
          "description": "a traffic conflict found by `s2p conflicts` (one row of conflicts.csv); "
                         "log time: the min-TTC frame, else the PET entry frame",
          "properties": {"frame": {"type": "integer"}, "id": {"type": "integer"},
                         "type": {"type": "string"}},
          "additionalProperties": {"type": ["number", "string", "null"]}}


@dataclass
class Conflicts:
    """The rows of a conflicts.csv: ``columns`` name -> (K,) array (numbers as float, NaN for
    an empty field; TEXT columns as str), in the file's order."""

    columns: dict

    def __len__(self) -> int:
        return len(self.columns["track_a"])

    def frame(self) -> np.ndarray:
        """(K,) the frame each conflict is shown at: min-TTC frame, else the PET entry frame,
        else the encounter's first frame."""
        c = self.columns
        f = np.where(np.isfinite(c["min_ttc_frame"]), c["min_ttc_frame"], c["pet_enter_frame"])
        return np.where(np.isfinite(f), f, c["first_frame"]).astype(np.int64)

    def describe(self, k: int) -> str:
        c = self.columns

        def num(key: str, unit: str) -> str:
            return "none" if not math.isfinite(c[key][k]) else f"{c[key][k]:.2f} {unit}"

        ta = (f", TA {num('ta_s', 's')} at {num('conflicting_speed_mps', 'm/s')}"
              if "ta_s" in c and "conflicting_speed_mps" in c else "")
        return (f"conflict {k}: {c['type'][k]}, {c['class_a'][k]} {int(c['track_a'][k])} x "
                f"{c['class_b'][k]} {int(c['track_b'][k])}: min TTC {num('min_ttc_s', 's')}, "
                f"PET {num('pet_s', 's')}{ta}")


def read_conflicts(path: str | Path) -> Conflicts:
    """Read a conflicts.csv; errors name the file, line and column."""
    path = Path(path)
    rows = list(csv.reader(io.StringIO(read_text(path, "conflicts file"))))
    header = [h.strip() for h in rows[0]] if rows else []
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise InputError(f"expected a conflicts.csv written by `s2p conflicts`; missing columns "
                         f"{', '.join(missing)}", file=path, line=1)
    cols: dict[str, list] = {h: [] for h in header}
    for lineno, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(header):
            raise InputError(f"expected {len(header)} fields, got {len(row)}", file=path, line=lineno)
        for h, v in zip(header, row):
            if h in TEXT:
                cols[h].append(v.strip())
                continue
            try:
                x = float(v) if v.strip() else math.nan
            except ValueError:
                raise InputError(f"expected a number or nothing, got {v!r}", file=path,
                                 line=lineno, field=h) from None
            if math.isinf(x) or (h in ("track_a", "track_b") and not math.isfinite(x)):
                raise InputError(f"expected a finite number, got {v!r}", file=path, line=lineno,
                                 field=h)
            cols[h].append(x)
    return Conflicts({h: np.array(v, dtype=object if h in TEXT else np.float64)
                      for h, v in cols.items()})


def _outline(xy: np.ndarray, heading: np.ndarray, size: np.ndarray, z: float = 0.05) -> list:
    """Closed footprint outlines (list of (5, 3) strips) slightly above the ground."""
    from seg2pose.safety.footprints import corners

    c = corners(np.atleast_2d(xy), np.atleast_1d(heading), np.atleast_2d(size))
    return [np.c_[np.r_[q, q[:1]], np.full(5, z)] for q in c]


def _pair(tracks, a: int, b: int, f0: int, f1: int):
    sel = np.flatnonzero(np.isin(tracks.track_id, [a, b]) & (tracks.frame >= f0) & (tracks.frame <= f1))
    return tracks.take(sel)


def pair_series(tracks, conflicts: Conflicts, k: int, opts=None):
    """(frames (P,), TTC (P,) s with NaN, distance (P,) m, Tracks of the pair, Motion) of
    conflict ``k`` over its encounter, recomputed from ``tracks`` with ``opts``
    (ConflictOptions; default: the defaults)."""
    from seg2pose.safety.conflicts import ConflictOptions, pair_frames
    from seg2pose.safety.kinematics import motion

    c = conflicts.columns
    opts = opts or ConflictOptions()
    margin = int(math.ceil(opts.motion.max_window_s * tracks.fps)) + 2
    sub = _pair(tracks, int(c["track_a"][k]), int(c["track_b"][k]),
                int(c["first_frame"][k]) - margin, int(c["last_frame"][k]) + margin)
    mot = motion(sub, opts.motion)
    pf = pair_frames(sub, mot, opts)
    keep = (sub.frame[pf.a] >= c["first_frame"][k]) & (sub.frame[pf.a] <= c["last_frame"][k])
    return sub.frame[pf.a][keep], pf.ttc[keep], pf.distance[keep], sub, mot


def log_conflicts(rec, conflicts: Conflicts, poses: PoseTable, fps: float, tb, first: int,
                  last: int) -> int:
    """Log the conflicts within frames [first, last] (their tracks from ``poses``, the run's
    pose table) to ``rec``; returns how many were logged."""
    import rerun as rr

    from seg2pose.safety.tracks import from_poses

    tracks, _ = from_poses(poses, fps)
    frames = conflicts.frame()
    c = conflicts.columns
    _log_map_and_chart(rec, conflicts, frames, first, last)
    shown = 0
    for k in range(len(conflicts)):
        if not (first <= frames[k] <= last):
            continue
        shown += 1
        f_end = int(min(frames[k] + HOLD_S * fps, last))
        rec.send_columns(EVENTS, indexes=tb.rerun_columns([frames[k]]),
                         columns=rr.TextLog.columns(text=[conflicts.describe(k)], level=["WARN"]))
        fr, x, d, sub, mot = pair_series(tracks, conflicts, k)
        near = (fr >= frames[k] - BEFORE_S * fps) & (fr <= f_end)
        fr, x, d = fr[near], x[near], d[near]
        send_scalars(rec, f"conflicts/ttc/c{k}", tb, fr, x)
        send_scalars(rec, f"conflicts/distance/c{k}", tb, fr, d)
        ent = f"world/conflicts/c{k}"
        if math.isfinite(c["min_ttc_frame"][k]):
            f = int(c["min_ttc_frame"][k])
            rows = np.flatnonzero(sub.frame == f)
            ttc = float(c["min_ttc_s"][k])
            now = _outline(sub.xy[rows], mot.heading[rows], sub.size[rows])
            ahead = sub.xy[rows] + mot.vel[rows] * ttc
            paths = [np.c_[np.r_[[p], [q]], np.full(2, 0.05)] for p, q in zip(sub.xy[rows], ahead)]
            pred = _outline(ahead, mot.heading[rows], sub.size[rows])
            _log_at(rec, tb, f, f_end, f"{ent}/now", rr.LineStrips3D(now, colors=RED, radii=0.08))
            _log_at(rec, tb, f, f_end, f"{ent}/predicted",
                    rr.LineStrips3D(paths + pred, colors=ORANGE, radii=0.04))
        if math.isfinite(c["pet_exit_frame"][k]):
            first_id = int(c["pet_first_track"][k])
            second_id = int(c["track_b"][k] if first_id == int(c["track_a"][k]) else c["track_a"][k])
            fx, fe = int(c["pet_exit_frame"][k]), int(c["pet_enter_frame"][k])
            r1 = np.flatnonzero((sub.track_id == first_id) & (sub.frame == fx))
            r2 = np.flatnonzero((sub.track_id == second_id) & (sub.frame == fe))
            rows = np.r_[r1, r2]
            if len(rows):
                _log_at(rec, tb, fe, int(fe + HOLD_S * fps), f"{ent}/pet",
                        rr.LineStrips3D(_outline(sub.xy[rows], mot.heading[rows], sub.size[rows]),
                                        colors=YELLOW, radii=0.06))
    return shown


def _log_map_and_chart(rec, conflicts: Conflicts, frames: np.ndarray, first: int, last: int) -> None:
    """The conflict map (world/conflicts/map) and the TCT chart (conflicts/tct), static, of
    the conflicts within [first, last] (columns of an older conflicts.csv missing: skipped)."""
    import rerun as rr

    from seg2pose.safety.evasive import tct_boundary_s

    c = conflicts.columns
    inside = (frames >= first) & (frames <= last)
    if "min_ttc_x" in c:
        m = inside & np.isfinite(c["min_ttc_x"])
        if m.any():
            pts = np.c_[c["min_ttc_x"][m], c["min_ttc_y"][m], np.full(int(m.sum()), 0.1)]
            labels = [f"c{k}: {c['type'][k]}, TTC {c['min_ttc_s'][k]:.2f} s" for k in np.flatnonzero(m)]
            rec.log("world/conflicts/map", rr.Points3D(pts, colors=RED, radii=0.5, labels=labels), static=True)
    if "ta_s" in c and "conflicting_speed_mps" in c:
        m = inside & np.isfinite(c["ta_s"]) & np.isfinite(c["conflicting_speed_mps"])
        v = np.linspace(0, 30, 50)
        rec.log("conflicts/tct/boundary", rr.LineStrips2D([np.c_[tct_boundary_s(v), -v * 3.6]], colors=(0, 0, 0)),
                static=True)
        if m.any():
            ta, kmh = c["ta_s"][m], c["conflicting_speed_mps"][m] * 3.6
            # the severity the table was made with (its boundary may be a study's own curve)
            serious = (c["tct_severity"][m] == "serious" if "tct_severity" in c
                       else ta <= tct_boundary_s(c["conflicting_speed_mps"][m]))
            cols = np.where(serious[:, None], np.array(RED), np.array((40, 90, 255)))
            labels = [f"c{k}: TA {c['ta_s'][k]:.2f} s at {c['conflicting_speed_mps'][k] * 3.6:.0f} km/h"
                      for k in np.flatnonzero(m)]
            # y down in a 2D view: speeds are drawn negative so that faster is higher
            rec.log("conflicts/tct/points", rr.Points2D(np.c_[ta, -kmh], colors=cols, radii=0.05, labels=labels),
                    static=True)
            if "ta_lo_s" in c:
                lo, hi = c["ta_lo_s"][m], c["ta_hi_s"][m]
                ok = np.isfinite(lo) & np.isfinite(hi)
                if ok.any():
                    bars = [np.array([[a, -y], [b, -y]]) for a, b, y in zip(lo[ok], hi[ok], kmh[ok])]
                    rec.log("conflicts/tct/intervals", rr.LineStrips2D(bars, colors=(120, 120, 120)), static=True)


def _log_at(rec, tb, frame: int, until: int, ent: str, archetype) -> None:
    """``archetype`` at ``ent`` from ``frame``, cleared after ``until``."""
    import rerun as rr

    for f, what in ((frame, archetype), (until + 1, rr.Clear(recursive=False))):
        rec.set_time(L.TIMELINE, sequence=int(f))
        ns = tb.ns1(int(f))
        if tb.start_ns is not None:
            rec.set_time(L.TIME, timestamp=np.datetime64(ns, "ns"))
        else:
            rec.set_time(L.TIME, duration=np.timedelta64(ns, "ns"))
        rec.log(ent, what)
    rec.reset_time()


def views():
    """The blueprint's views of conflicts: TTC and distance plots and the events' list."""
    import rerun.blueprint as rrb

    return [rrb.TimeSeriesView(origin="conflicts/ttc", name="conflicts: TTC (s)"),
            rrb.TimeSeriesView(origin="conflicts/distance", name="conflicts: distance (m)"),
            rrb.Spatial2DView(origin="conflicts/tct", name="conflicts: TCT chart (TA s, -speed km/h)"),
            rrb.TextLogView(origin=EVENTS, name="conflicts")]


def mcap_items(conflicts: Conflicts, tb, first: int, last: int):
    """(log time ns, rank, topic, (schema, message)) per conflict in [first, last]: the
    conflicts as events on ``TOPIC`` (JSON), every column of the row in the message."""
    frames = conflicts.frame()
    c = conflicts.columns
    out = []
    for k in range(len(conflicts)):
        if first <= frames[k] <= last:
            msg: dict[str, Any] = {"frame": int(frames[k]), "id": k}
            for h, v in c.items():
                x = v[k]
                msg[h] = x if isinstance(x, str) else (float(x) if math.isfinite(x) else None)
            out.append((tb.ns1(int(frames[k])), 1, TOPIC, (SCHEMA, msg)))
    return sorted(out, key=lambda m: m[0])
