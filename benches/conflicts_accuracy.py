"""Conflicts from estimated tracks against conflicts from the truth, on synthetic scenes.

For each scene and run (the run's frames, e.g. ``s2p run --split test``), `s2p conflicts` is
computed on the truth (SCENE/gt/poses.csv over the run's frames) and on the run, every
encounter kept (``--all-pairs``), pedestrian pairs left out as by default. Synthetic runs keep
the truth's track ids, so encounters pair up by their two ids. Reported:

- share found: of the truth's conflicts at min TTC <= 1.5 s (PET <= 5 s), the share whose pair
  also has min TTC <= 1.5 s (PET <= 5 s) in the run; false alarms: the run's conflicts whose
  pair is none in the truth;
- indicator errors: median and 90th percentile of |run - truth| of min TTC and PET over the
  pairs where both have the indicator (and the truth's is at or below the threshold);
- Time-to-Accident and conflicting speed: over the truth's TTC conflicts with a TA (an evasive
  action on a collision course), how many also have one in the run, whether it is the same
  road user that evades, and the median / 90th percentile of |run - truth| of TA and of the
  conflicting speed;
- coverage: the share of those truth values inside the run's 90 % interval (sampling within
  r90: per class from ``--r90``, or per pose from ``--r90-calibration``, the error bars
  ``s2p run --r90 CAL`` would write into the run's poses.csv, computed from its views.csv;
  runs of uncalibrated scenes carry no r90_m), and the intervals' median width.

    PYTHONPATH=. .venv/bin/python benches/conflicts_accuracy.py --pair SCENE RUN [--pair ...]
        --r90 car=0.93,pedestrian=0.39,bicyclist=0.79 [--draws 200] [--window 1.0] [--corr 3.0]
        [--heading90 car=40,pedestrian=61,bicyclist=16]
    PYTHONPATH=. .venv/bin/python benches/conflicts_accuracy.py --pair SCENE RUN
        --r90-calibration R90.json   # per-pose r90_m (s2p calibrate-errors on a tuning scene's run)

Prints one line per run and the pooled figures.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from seg2pose.io.poses import read_poses
from seg2pose.io.run import read_run
from seg2pose.io.scene import load_scene
from seg2pose.method.fusion import fuse
from seg2pose.method.uncertainty import read_calibration, view_r90
from seg2pose.safety.conflicts import ConflictOptions, analyse
from seg2pose.safety.intervals import IntervalOptions, conflict_intervals
from seg2pose.safety.kinematics import MotionOptions
from seg2pose.safety.tracks import from_poses, load_tracks, scene_class_sizes

TTC, PET = 1.5, 5.0


def table_of(tracks, opts):
    t = analyse(tracks, opts)
    c = t.columns
    return t, {(int(a), int(b)): i for i, (a, b) in enumerate(zip(c["track_a"], c["track_b"]))}


def needed(exact: float, centre: float, below: float, above: float) -> float:
    """The least spread factor (``IntervalOptions.spread``) whose interval holds ``exact``."""
    if exact <= centre:
        return (centre - exact) / below if below > 0 else (0.0 if exact == centre else np.inf)
    return (exact - centre) / above if above > 0 else np.inf


def pose_r90(scene: Path, run: Path, calibration: Path, est) -> np.ndarray:
    """(N,) r90_m of each row of ``est`` (the run's tracks) as ``s2p run --r90 calibration``
    gives it (``seg2pose.method.pipeline``: each view's bar, then the fused pose's), computed
    from the run's views.csv; NaN for rows without one."""
    cal = read_calibration(calibration)
    rr = read_run(run)
    sc = load_scene(scene)
    views = rr.views
    views.r90 = view_r90(cal, sc, views)
    poses = fuse(views, sc, int(rr.meta.get("smooth_frames") or 0), r90=cal)
    at = {(int(f), int(t)): r for f, t, r in zip(poses.frame, poses.track_id, poses.r90)}
    return np.array([at.get((int(f), int(t)), np.nan) for f, t in zip(est.frame, est.track_id)])


def measure(scene: Path, run: Path, r90: dict | None, draws: int, seed: int,
            window_s: float | None = None, corr_s: float = 3.0, heading90: dict | None = None,
            spread: tuple[float, float, float] | None = None, calibration: Path | None = None) -> dict:
    est, _ = load_tracks(run)
    if calibration is not None:
        est.r90 = pose_r90(scene, run, calibration, est)
    fps = est.fps
    gt = read_poses(scene / "gt" / "poses.csv").in_frames((int(est.frame.min()), int(est.frame.max())))
    truth, _ = from_poses(gt, fps, sizes=scene_class_sizes(scene / "gt" / "poses.csv"))
    opts = ConflictOptions(all_pairs=True, motion=MotionOptions(window_s=window_s))
    tt, ti = table_of(truth, opts)
    et, ei = table_of(est, opts)
    if r90 is not None or calibration is not None:
        ft = et.tracks  # the analysed tracks (short gaps filled; r90 filled as s2p conflicts does)
        if calibration is None:
            ft.r90 = np.array([r90[str(c)] for c in ft.cls], float)
        # the run's conflicts, and its rows of the truth's TTC conflicts and PET pairs (their
        # intervals are the ones coverage is measured on)
        tcol = tt.columns
        truth_keys = {k for k, i in ti.items() if tcol["min_ttc_s"][i] <= TTC or tcol["pet_s"][i] <= PET}
        want = et.columns["conflict"].astype(bool) | np.array([k in truth_keys for k in ei], bool)
        conf = et.take(want)
        h90 = None if heading90 is None else np.radians([heading90[str(c)] for c in ft.cls])
        io_ = IntervalOptions(draws=draws, seed=seed, corr_s=corr_s, details=True,
                              **({} if spread is None else {"spread": spread}))
        iv = conflict_intervals(ft, conf, opts, io_, heading90=h90)
        pos = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(conf.columns["track_a"],
                                                                  conf.columns["track_b"]))}
    out = {"scene": scene.name, "run": run.name, "method": json.loads((run / "run.json").read_text()).get("method")}
    tc, ec = tt.columns, et.columns
    for name, col, thr, lo, hi in (("ttc", "min_ttc_s", TTC, "min_ttc_lo_s", "min_ttc_hi_s"),
                                   ("pet", "pet_s", PET, "pet_lo_s", "pet_hi_s")):
        true_conf = [k for k, i in ti.items() if tc[col][i] <= thr]
        est_conf = [k for k, i in ei.items() if ec[col][i] <= thr]
        found = [k for k in true_conf if k in ei and ec[col][ei[k]] <= thr]
        false = [k for k in est_conf if not (k in ti and tc[col][ti[k]] <= thr)]
        both = [k for k in true_conf if k in ei and np.isfinite(ec[col][ei[k]])]
        err = np.array([abs(ec[col][ei[k]] - tc[col][ti[k]]) for k in both])
        out[name] = {"truth": len(true_conf), "found": len(found), "est": len(est_conf),
                     "false": len(false), "err": err}
        if r90 is not None or calibration is not None:
            inside, width, need = [], [], []
            base = lo[:-5]  # "min_ttc" / "pet"
            for k in both:
                if k in pos and np.isfinite(iv[lo][pos[k]]):
                    inside.append(iv[lo][pos[k]] - 1e-9 <= tc[col][ti[k]] <= iv[hi][pos[k]] + 1e-9)
                    width.append(iv[hi][pos[k]] - iv[lo][pos[k]])
                    need.append(needed(tc[col][ti[k]], *(iv[f"{base}_{p}"][pos[k]]
                                                         for p in ("centre", "below", "above"))))
            out[name]["inside"] = np.array(inside, bool)
            out[name]["width"] = np.array(width)
            out[name]["need"] = np.array(need)
    # SSAM conflicts by the truth's type: found (a conflict in the run too), missed; the run's
    # false ones by their own type
    types: dict[str, dict[str, int]] = {}
    for k, i in ti.items():
        if tc["conflict"][i] == 1:
            d = types.setdefault(tc["type"][i], {"truth": 0, "found": 0, "false": 0})
            d["truth"] += 1
            d["found"] += int(k in ei and ec["conflict"][ei[k]] == 1)
    for k, i in ei.items():
        if ec["conflict"][i] == 1 and not (k in ti and tc["conflict"][ti[k]] == 1):
            types.setdefault(ec["type"][i], {"truth": 0, "found": 0, "false": 0})["false"] += 1
    out["types"] = types
    ta = [k for k, i in ti.items() if tc["min_ttc_s"][i] <= TTC and np.isfinite(tc["ta_s"][i])]
    both = [k for k in ta if k in ei and np.isfinite(ec["ta_s"][ei[k]])]
    out["ta"] = {"truth": len(ta), "found": len(both),
                 "same": sum(ec["evasive_track"][ei[k]] == tc["evasive_track"][ti[k]] for k in both),
                 "err": np.array([abs(ec["ta_s"][ei[k]] - tc["ta_s"][ti[k]]) for k in both]),
                 "speed_err": np.array([abs(ec["conflicting_speed_mps"][ei[k]]
                                            - tc["conflicting_speed_mps"][ti[k]]) for k in both])}
    if r90 is not None or calibration is not None:
        ks = [k for k in both if k in pos and np.isfinite(iv["ta_lo_s"][pos[k]])]
        out["ta"]["inside"] = np.array([iv["ta_lo_s"][pos[k]] - 1e-9 <= tc["ta_s"][ti[k]]
                                        <= iv["ta_hi_s"][pos[k]] + 1e-9 for k in ks], bool)
        out["ta"]["need"] = np.array([needed(tc["ta_s"][ti[k]], *(iv[f"ta_{p}"][pos[k]] for p in
                                                                  ("centre", "below", "above"))) for k in ks])
    return out


def p90(x) -> str:
    """The 90th percentile of ``x`` (inf: no spread holds it), formatted."""
    x = np.asarray(x, float)
    if not len(x):
        return "nan"
    v = float(np.percentile(np.minimum(x, 1e9), 90))
    return "inf" if v >= 1e8 else f"{v:.2f}"


def ta_line(m: dict) -> str:
    def q(x, p):
        return np.percentile(x, p) if len(x) else float("nan")

    return (f"ta: truth's TTC conflicts with a TA {m['truth']}, with a TA in the run too "
            f"{m['found']} (same evasive road user {m['same']}); |TA error| median "
            f"{q(m['err'], 50):.2f} s, p90 {q(m['err'], 90):.2f} s; |conflicting speed error| "
            f"median {q(m['speed_err'], 50):.2f} m/s, p90 {q(m['speed_err'], 90):.2f} m/s"
            + (f"; TA coverage {100 * m['inside'].mean():.0f} % (n={len(m['inside'])}), spread needed p90 "
               f"{p90(m['need'])}" if len(m.get("inside", [])) else ""))


def line(name: str, m: dict) -> str:
    e = m["err"]
    s = (f"{name}: truth {m['truth']}, found {m['found']} ({100 * m['found'] / max(m['truth'], 1):.0f} %), "
         f"run's {m['est']} with {m['false']} false; |error| median "
         f"{np.median(e) if len(e) else float('nan'):.2f} s, p90 "
         f"{np.percentile(e, 90) if len(e) else float('nan'):.2f} s (n={len(e)})")
    if "inside" in m:
        s += (f"; coverage {100 * m['inside'].mean() if len(m['inside']) else float('nan'):.0f} % "
              f"(n={len(m['inside'])}), width median "
              f"{np.median(m['width']) if len(m['width']) else float('nan'):.2f} s, spread needed p90 "
              f"{p90(m['need'])}")
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pair", nargs=2, action="append", metavar=("SCENE", "RUN"), required=True)
    ap.add_argument("--r90", default=None, help="class=metres,... (90 %% error radius per class)")
    ap.add_argument("--r90-calibration", type=Path, default=None, help="per-pose r90_m from this "
                    "calibration (s2p calibrate-errors) applied to each run's views, as s2p run --r90 does")
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--window", type=float, default=None, help="a fixed smoothing window, s (--window of s2p "
                    "conflicts; default: each track's from its noise)")
    ap.add_argument("--corr", type=float, default=3.0, help="error correlation time, s (--error-corr)")
    ap.add_argument("--spread", type=float, nargs=3, default=None, metavar=("TTC", "TA", "PET"),
                    help="the intervals' spread factors (default: IntervalOptions')")
    ap.add_argument("--heading90", default=None, help="class=degrees,... (90 %% heading error per class; "
                    "intervals then also perturb headings)")
    a = ap.parse_args()
    h90 = None if a.heading90 is None else {k: float(v) for k, v in (x.split("=") for x in a.heading90.split(","))}
    r90 = None if a.r90 is None else {k: float(v) for k, v in (x.split("=") for x in a.r90.split(","))}
    pooled: dict = {}
    for scene, run in a.pair:
        m = measure(Path(scene), Path(run), r90, a.draws, a.seed, a.window, a.corr, h90,
                    None if a.spread is None else tuple(a.spread), a.r90_calibration)
        print(f"{m['scene']} {m['run']} ({m['method']})")
        print("  " + ta_line(m["ta"]))
        print("  SSAM conflicts by type (truth / found / missed / false): " + "; ".join(
            f"{t} {d['truth']}/{d['found']}/{d['truth'] - d['found']}/{d['false']}"
            for t, d in sorted(m["types"].items())))
        for name in ("ttc", "pet", "ta"):  # (the types are per run only)
            if name != "ta":
                print("  " + line(name, m[name]))
            p = pooled.setdefault((m["method"], name), {})
            for k, v in m[name].items():
                p[k] = (np.r_[p[k], v] if isinstance(v, np.ndarray) else p.get(k, 0) + v) if k in p else v
    print("pooled")
    for (method, name), m in pooled.items():
        print(f"  {method}: " + (ta_line(m) if name == "ta" else line(name, m)))


if __name__ == "__main__":
    main()
