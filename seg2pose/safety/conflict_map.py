"""The conflict map (``s2p conflicts --map``) and the TCT severity chart, as PNG pictures.

The map shows every road user's path (thin, grey) and, per conflict, the predicted point of
contact at its minimum TTC (a dot coloured by type, its size by how small the TTC is) with a
line from where the conflict started to where it ended; PET-only encounters as open circles
at the second road user's position as it entered the spot. Axes in metres, the ground plane
of the tracks. The chart puts each conflict's Time-to-Accident against its conflicting speed,
with the TCT's serious / slight boundary (``evasive.tct_boundary_s``).
"""

from __future__ import annotations

import io

import numpy as np

from seg2pose.safety.evasive import EvasiveOptions, tct_boundary_s

TYPE_COLOURS = {"rear-end": "tab:blue", "lane-change": "tab:cyan", "crossing": "tab:orange",
                "head-on": "tab:red", "pedestrian": "tab:purple", "bicyclist": "tab:green",
                "unknown": "tab:gray"}


def map_points(table) -> dict:
    """The points of the map: conflicts (rows with a collision course at or below the
    threshold): x, y (K,) of the predicted contact, type, min TTC; PET-only: x, y of the
    second road user's entry."""
    c = table.columns
    conf = c["conflict"] == 1
    out = {"x": c["min_ttc_x"][conf], "y": c["min_ttc_y"][conf], "type": c["type"][conf],
           "ttc": c["min_ttc_s"][conf], "start": np.c_[c["start_x"][conf], c["start_y"][conf]],
           "end": np.c_[c["end_x"][conf], c["end_y"][conf]]}
    po = np.flatnonzero(c["pet_only"] == 1)
    xy = np.zeros((0, 2))
    if len(po) and table.pets is not None and table.tracks is not None:
        pr = table.pets
        key = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(pr.track_a, pr.track_b))}
        rows = [pr.row_second[key[(int(c["track_a"][k]), int(c["track_b"][k]))]] for k in po]
        xy = table.tracks.xy[np.array(rows, np.int64)]
    out["pet_xy"] = xy
    return out


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


def map_png(table, title: str = "conflict map") -> bytes:
    """The conflict map of ``table`` (a ConflictTable with its tracks) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = map_points(table)
    fig, ax = plt.subplots(figsize=(7, 7))
    tr = table.tracks
    if tr is not None and len(tr):
        step = max(1, len(tr) // 200000)  # a long recording: every few rows is enough
        ax.scatter(tr.xy[::step, 0], tr.xy[::step, 1], s=0.2, c="0.8", linewidths=0, rasterized=True)
    for (x0, y0), (x1, y1) in zip(p["start"], p["end"]):
        ax.plot([x0, x1], [y0, y1], c="0.4", lw=0.6)
    for name, colour in TYPE_COLOURS.items():
        m = p["type"] == name
        if m.any():
            size = 20 + 60 * np.clip(1.5 - p["ttc"][m], 0, 1.5)
            ax.scatter(p["x"][m], p["y"][m], s=size, c=colour, label=f"{name} ({int(m.sum())})",
                       edgecolors="k", linewidths=0.4, zorder=3)
    if len(p["pet_xy"]):
        ax.scatter(p["pet_xy"][:, 0], p["pet_xy"][:, 1], s=18, facecolors="none", edgecolors="0.3",
                   label=f"PET only ({len(p['pet_xy'])})", zorder=2)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{title}: minimum-TTC points (larger: smaller TTC)")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    data = _png(fig)
    plt.close(fig)
    return data


def tct_chart_png(ta_s: np.ndarray, speed_mps: np.ndarray, lo: np.ndarray | None = None,
                  hi: np.ndarray | None = None, evasive: EvasiveOptions = EvasiveOptions()) -> bytes:
    """The TCT chart: conflicting speed (km/h) against TA (s), the serious / slight boundary
    (``evasive``'s: ``evasive.tct_boundary_s``), and each conflict's point with its TA
    interval (``lo``, ``hi``; none drawn where NaN)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    v = np.linspace(0, 30, 100)
    label = "serious / slight boundary" + ("" if evasive.tct_curve else
                                           f" (stand-in: stopping at {evasive.tct_decel_mps2:g} m/s²)")
    ax.plot(tct_boundary_s(v, evasive), v * 3.6, c="k", lw=1, label=label)
    ok = np.isfinite(ta_s) & np.isfinite(speed_mps)
    if lo is not None and hi is not None:
        iv = ok & np.isfinite(lo) & np.isfinite(hi)
        ax.errorbar(ta_s[iv], speed_mps[iv] * 3.6, xerr=[ta_s[iv] - lo[iv], hi[iv] - ta_s[iv]],
                    fmt="none", ecolor="0.5", lw=0.8)
    serious = ok & (ta_s <= tct_boundary_s(speed_mps, evasive))
    ax.scatter(ta_s[serious], speed_mps[serious] * 3.6, c="tab:red", s=18, label="serious")
    ax.scatter(ta_s[ok & ~serious], speed_mps[ok & ~serious] * 3.6, c="tab:blue", s=18, label="slight")
    ax.set_xlim(0, max(4.5, float(np.nanmax(ta_s[ok], initial=0)) + 0.5))
    ax.set_ylim(0, 100)
    ax.set_xlabel("Time-to-Accident (s)")
    ax.set_ylabel("conflicting speed (km/h)")
    ax.legend(loc="upper left", fontsize=8)
    data = _png(fig)
    plt.close(fig)
    return data


def tct_chart_of(table, evasive: EvasiveOptions = EvasiveOptions()) -> bytes:
    """The TCT chart of the rows of ``table`` (with their TA intervals, if sampled) as PNG
    bytes, with ``evasive``'s severity boundary (``s2p conflicts`` writes it, with the map,
    in the same set as its CSVs)."""
    c = table.columns
    lo, hi = c.get("ta_lo_s"), c.get("ta_hi_s")
    return tct_chart_png(np.asarray(c["ta_s"], float), np.asarray(c["conflicting_speed_mps"], float),
                         None if lo is None else np.asarray(lo, float), None if hi is None else np.asarray(hi, float),
                         evasive)
