"""Safety commands: ``s2p conflicts`` (traffic conflicts and surrogate safety measures)."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from seg2pose.cli.common import SAFETY, parse_frames, speaks_flags
from seg2pose.core.errors import InputError, S2PError


def parse_r90(text: str | None, field: str = "--r90", unit: str = "METRES",
              hi: float = 1000.0) -> dict[str, float] | None:
    """``car=1.2,pedestrian=0.6`` -> {class: value} (values in 0..``hi``)."""
    if text is None:
        return None
    out = {}
    for item in text.split(","):
        name, sep, val = item.partition("=")
        try:
            v = float(val)
            if not sep or not name.strip() or not (0 <= v <= hi):
                raise ValueError
        except ValueError:
            raise InputError(f"expected CLASS={unit}[,CLASS={unit}...], got {text!r}",
                             field=field) from None
        out[name.strip()] = v
    return out


def parse_tct_curve(text: str | None) -> tuple[tuple[float, float], ...]:
    """``10:0.5,50:1.5`` -> ((10.0, 0.5), (50.0, 1.5)) (km/h, seconds; at least two points,
    speeds distinct and not negative); None -> () (the stand-in boundary)."""
    if text is None:
        return ()
    pts = []
    for item in text.split(","):
        kmh, sep, ta = item.partition(":")
        try:
            p = (float(kmh), float(ta))
            if not sep or p[0] < 0 or p[1] < 0:
                raise ValueError
        except ValueError:
            raise InputError(f"expected KMH:SECONDS[,KMH:SECONDS...], got {text!r}", field="--tct-curve") from None
        pts.append(p)
    if len(pts) < 2 or len({p[0] for p in pts}) < len(pts):
        raise InputError(f"expected at least two points of distinct speeds, got {text!r}", field="--tct-curve")
    return tuple(pts)


def parse_spread(text: str) -> tuple[float, float, float]:
    """``2,2.5,2`` -> (2.0, 2.5, 2.0): three positive factors (min TTC, TA, PET)."""
    try:
        v = tuple(float(x) for x in text.split(","))
        if len(v) != 3 or min(v) <= 0:
            raise ValueError
    except ValueError:
        raise InputError(f"expected three positive numbers TTC,TA,PET, got {text!r}",
                         field="--interval-spread") from None
    return (v[0], v[1], v[2])


def parse_clock(text: str | None) -> int:
    if text is None:
        return 0
    from seg2pose.io.tanalyst import parse_time

    try:
        return parse_time(text)
    except InputError:
        raise InputError(f"expected HH:MM:SS.mmm, got {text!r}", field="--start") from None


def _scene_of(tracks: Path) -> Path:
    """The scene folder of a run folder (its run.json's "scene")."""
    from seg2pose.io.run import read_run_meta

    if not tracks.is_dir():
        raise InputError("--review needs a run folder (made by `s2p run`), not a file", file=tracks)
    scene = read_run_meta(tracks).get("scene")
    if not isinstance(scene, str):
        raise InputError("run.json names no scene folder", file=tracks / "run.json")
    return (tracks / scene).resolve()


def _say_least(c: dict) -> None:
    """One line on the conflict with the least TTC (the worked example's numbers)."""
    import numpy as np

    k = np.flatnonzero(c["conflict"] == 1)
    if not len(k):
        return
    i = k[np.nanargmin(c["min_ttc_s"][k])]
    ta = c["ta_s"][i]
    typer.echo(f"least TTC {c['min_ttc_s'][i]:.3f} s: {c['type'][i]}, {c['class_a'][i]} {int(c['track_a'][i])} x "
               f"{c['class_b'][i]} {int(c['track_b'][i])} at frame {int(c['min_ttc_frame'][i])}; TA "
               + (f"{ta:.3f} s at {c['conflicting_speed_mps'][i]:.1f} m/s by {int(c['evasive_track'][i])} "
                  f"({c['tct_severity'][i]})" if np.isfinite(ta) else "none"))


def register(app: typer.Typer) -> None:
    app.command("conflicts", rich_help_panel=SAFETY)(speaks_flags(_locked(conflicts)))


_OUTPUT_OPTIONS = {"out": "-o", "pet_only": "--pet-only", "conflict_map": "--map", "tct_chart": "--tct-chart",
                   "review": "--review"}


def _distinct_outputs(kwargs: dict) -> None:
    """Two output options naming one file would have one output silently overwrite the other
    (the set would commit two builds to one name): refused before anything is computed."""
    seen: dict[Path, str] = {}
    for key, flag in _OUTPUT_OPTIONS.items():
        path = kwargs.get(key)
        if path is None:
            continue
        where = Path(path).absolute()
        if where in seen:
            raise S2PError(f"{path}: named by both {seen[where]} and {flag}; give each output its own file")
        seen[where] = flag


def _locked(command):
    """``conflicts`` with its outputs locked from the start of the analysis (it locked only
    for its final writes: two runs into one file both computed, the last one won)."""
    import functools

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        from seg2pose.io.atomic import holding

        _distinct_outputs(kwargs)
        with holding(*(kwargs.get(k) for k in _OUTPUT_OPTIONS)):
            return command(*args, **kwargs)
    return wrapper


def conflicts(
    tracks: Path = typer.Argument(
        ...,
        help="run folder (made by `s2p run`), a poses.csv (frame,track_id,class,x,y,z,heading[,l,w,h][,r90_m]) or a "
             "T-Analyst tracks CSV",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="output conflicts.csv"),
    fps: float | None = typer.Option(
        None, "--fps",
        help="frames per second (needed when no scene says it: a poses.csv outside a run or scene, a T-Analyst file)",
    ),
    frames: str | None = typer.Option(None, "--frames", help="only frames A:B (inclusive); default: all"),
    start: str | None = typer.Option(
        None, "--start", help="T-Analyst file: the time stamp of frame 0, HH:MM:SS.mmm (default 00:00:00.000)",
    ),
    ttc_s: float = typer.Option(
        1.5, "--ttc", min=0.0,
        help="SSAM's conflict threshold, seconds: a collision course with TTC at or below it makes a conflict",
    ),
    pet_s: float = typer.Option(
        5.0, "--pet", min=0.0, help="PET reported up to this, seconds (and the PET-only list's threshold)",
    ),
    horizon_s: float = typer.Option(
        5.0, "--horizon", min=0.1,
        help="TTC is looked for this many seconds ahead (beyond it: none); road users are compared when they "
             "could meet within it at their speeds, however far apart",
    ),
    max_gap: float = typer.Option(
        1.0, "--max-gap", min=0.0,
        help="missing frames of a track are interpolated over gaps up to this many seconds; longer gaps split "
             "the track's smoothing",
    ),
    window_s: float | None = typer.Option(
        None, "--window", min=0.01,
        help="a fixed width (seconds) of the centred fits that give velocity and acceleration; default: each "
             "track's from its noise",
    ),
    brake: float = typer.Option(
        3.0, "--brake", min=0.0, help="evasive action: braking at least this hard, m/s^2 (for Time-to-Accident)",
    ),
    swerve: float = typer.Option(
        3.0, "--swerve", min=0.0, help="evasive action: lateral acceleration of at least this, m/s^2",
    ),
    yaw: float | None = typer.Option(
        None, "--yaw", min=0.0,
        help="evasive action: also a turning rate of at least this, degrees/s (default: lateral acceleration only)",
    ),
    tct_decel: float = typer.Option(
        4.0, "--tct-decel", min=0.1,
        help="TCT severity: serious when TA <= the time to stop at this deceleration from the conflicting speed, "
             "m/s^2 (a stand-in for the TCT's published curve, which this tool does not have; see --tct-curve)",
    ),
    tct_curve: str | None = typer.Option(
        None, "--tct-curve",
        help="TCT severity boundary as points KMH:SECONDS,... (the digitised curve of the TCT chart, joined by "
             "straight lines; serious at or below it); replaces --tct-decel",
    ),
    pet_only: Path | None = typer.Option(
        None, "--pet-only", help="also write the PET-only encounters (PET <= --pet, no collision course) to this CSV",
    ),
    conflict_map: Path | None = typer.Option(
        None, "--map",
        help="also draw the conflict map (PNG): where the conflicts' minimum TTC and the PET-only encounters lie",
    ),
    tct_chart: Path | None = typer.Option(
        None, "--tct-chart",
        help="also draw the TCT chart (PNG): each conflict's Time-to-Accident against its conflicting speed, with "
             "its TA interval and the serious / slight boundary",
    ),
    all_pairs: bool = typer.Option(
        False, "--all-pairs",
        help="write every encounter with its indicators (flagged conflict / pet_only), not only conflicts",
    ),
    pedestrian_pairs: bool = typer.Option(
        False, "--pedestrian-pairs",
        help="also pairs of two pedestrians (left out by default: walking past each other is no traffic conflict)",
    ),
    draws: int = typer.Option(
        200, "--draws", min=0, help="error intervals: draws per conflict where poses carry r90_m (0: none)",
    ),
    r90: str | None = typer.Option(
        None, "--r90",
        help="error radius per class for poses without r90_m, e.g. car=1.2,pedestrian=0.6 (metres within which 90 "
             "percent of the positions lie; say where the figures come from)",
    ),
    heading90: str | None = typer.Option(
        None, "--heading90",
        help="heading error per class for the intervals, e.g. car=40,pedestrian=61,bicyclist=16 (degrees within which "
             "90 percent of the headings lie; the baseline's on synthetic seed 201); default: headings not perturbed",
    ),
    corr_s: float = typer.Option(
        3.0, "--error-corr", min=0.01, help="correlation time of pose errors for the intervals, seconds",
    ),
    spread: str | None = typer.Option(
        None, "--interval-spread",
        help="widening of the bootstrap's min TTC, TA and PET intervals, TTC,TA,PET (default 2.1,2.7,2.2: chosen "
             "so that 90 % intervals hold the truth 90 % of the time on tuning runs; docs/guide/conflicts.md)",
    ),
    seed: int = typer.Option(0, "--seed", help="seed of the interval draws"),
    workers: int = typer.Option(
        2, "--workers", min=1, help="processes the time chunks are analysed in (the result does not depend on it)",
    ),
    chunk_s: float = typer.Option(
        60.0, "--chunk", min=1.0,
        help="seconds of recording whose pair frames are held at once (memory then grows only with the poses "
             "themselves; the result does not depend on it)",
    ),
    review: Path | None = typer.Option(
        None, "--review",
        help="also write a review recording (.rrd) of the run's scene with the conflicts (TRACKS must be a run folder "
             "of a scene)",
    ),
    force: bool = typer.Option(False, "--force", help="overwrite an existing output"),
) -> None:
    """Find traffic conflicts in road-user tracks: TTC, PET, Time-to-Accident, SSAM's measures.

    A conflict is SSAM's: a collision course with TTC (Hayward 1972: current velocities from a
    smoother over the whole track, rectangular footprints) at or below --ttc; its PET is
    reported with it (--pet-only writes the encounters with PET <= --pet and no collision
    course). Per conflict: min TTC; Time-to-Accident and conflicting speed at the onset of the
    evasive action, with the TCT severity (Hyden 1987); MaxS, DeltaS, DR, MaxD, MaxDeltaV, the
    signed conflict angle and the type (rear-end, lane-change, crossing, head-on, pedestrian,
    bicyclist); the least gap between the footprints; positions for conflict maps; and, where
    the poses carry r90_m (or --r90 gives it), 90 % intervals of min TTC, PET and TA
    (docs/guide/conflicts.md)."""
    import numpy as np

    from seg2pose.core.say import say
    from seg2pose.io.atomic import atomic_write_bytes, atomic_write_text, check_writable, outputs
    from seg2pose.safety.conflicts import ConflictOptions, analyse
    from seg2pose.safety.evasive import EvasiveOptions
    from seg2pose.safety.gaps import jump_note, jumps
    from seg2pose.safety.intervals import IntervalOptions, conflict_intervals
    from seg2pose.safety.kinematics import MotionOptions
    from seg2pose.safety.table import INTERVAL_COLUMNS, format_conflicts
    from seg2pose.safety.tracks import load_tracks

    for extra in (pet_only, conflict_map, tct_chart):
        if extra is not None:
            check_writable(extra, force)
    check_writable(out, force)
    scene_dir = None
    if review is not None:
        check_writable(review, force)
        scene_dir = _scene_of(tracks)
    table_r90 = parse_r90(r90)
    spread_f = None if spread is None else parse_spread(spread)
    table_h90 = parse_r90(heading90, "--heading90", "DEGREES", 180.0)
    t0 = time.perf_counter()
    frame_range = parse_frames(frames)
    tr, notes = load_tracks(tracks, fps, parse_clock(start))
    if frame_range is not None:
        tr = tr.take((tr.frame >= frame_range[0]) & (tr.frame <= frame_range[1]))
    for n in notes:
        say(n, "note")
    if len(tr) == 0:
        raise S2PError(f"{tracks}: no poses of tracked road users")
    if table_r90 is not None:
        missing = sorted(set(tr.cls.astype(str)) - set(table_r90))
        if missing:
            raise InputError(f"no error radius for classes {', '.join(missing)}", field="--r90")
        per_class = np.array([table_r90[str(c)] for c in tr.cls], float)
        tr.r90 = per_class if tr.r90 is None else np.where(np.isfinite(tr.r90), tr.r90, per_class)
    if table_h90 is not None:
        missing = sorted(set(tr.cls.astype(str)) - set(table_h90))
        if missing:
            raise InputError(f"no heading error for classes {', '.join(missing)}",
                             field="--heading90")
    say(f"{len(tr):,} poses of {len(np.unique(tr.track_id)):,} road users, "
        f"{(tr.frame.max() - tr.frame.min() + 1) / tr.fps if len(tr) else 0:.0f} s at {tr.fps:g} fps")
    bad = jumps(tr)
    if len(bad):
        say(jump_note(tr, bad), "warning")
    opts = ConflictOptions(ttc_s=ttc_s, pet_s=pet_s, horizon_s=horizon_s, max_gap_s=max_gap,
                           evasive=EvasiveOptions(brake_mps2=brake, swerve_mps2=swerve, yaw_dps=yaw,
                                                  tct_decel_mps2=tct_decel, tct_curve=parse_tct_curve(tct_curve)),
                           all_pairs=all_pairs, pedestrian_pairs=pedestrian_pairs, chunk_s=chunk_s,
                           workers=workers, motion=MotionOptions(window_s=window_s))
    table = analyse(tr, opts, progress=lambda step: say(f"{step} ..."))
    for n in table.notes:
        say(n, "note")
    c = table.columns
    n_conf, n_pet = int(c["conflict"].sum()), int(c["pet_only"].sum())
    ft = table.tracks  # the tracks analysed: short gaps filled in
    assert ft is not None  # (analyse keeps them with the table)
    if draws > 0 and ft.r90 is not None and np.isfinite(ft.r90).any() and len(table):
        from tqdm import tqdm

        h90 = None if table_h90 is None else np.radians([table_h90[str(x)] for x in ft.cls])
        iopts = IntervalOptions(draws=draws, corr_s=corr_s, seed=seed,
                                spread=IntervalOptions.spread if spread_f is None else spread_f)
        iv = conflict_intervals(ft, table, opts, iopts,
                                heading90=h90, progress=lambda it: tqdm(it, desc="intervals", unit="pair"))
        table.columns.update({k: iv[k] for k in INTERVAL_COLUMNS})
    elif draws > 0:
        say("the poses carry no r90_m: error intervals none (give --r90 CLASS=METRES,... for "
            "a per-class error radius)", "note")
    # the pictures drawn before the commit (seconds of plotting kept out of it); the conflicts,
    # the PET-only encounters and the pictures as one set: a kill or refusal leaves all old
    pictures: dict[Path, bytes] = {}
    if conflict_map is not None:
        from seg2pose.safety.conflict_map import map_png

        pictures[conflict_map] = map_png(table)
    if tct_chart is not None:
        from seg2pose.safety.conflict_map import tct_chart_of

        pictures[tct_chart] = tct_chart_of(table.take(c["conflict"] == 1), opts.evasive)
    with outputs([out] + ([pet_only] if pet_only is not None else []) + list(pictures), force) as files:
        atomic_write_text(files.file(out), format_conflicts(table if all_pairs else table.take(c["conflict"] == 1),
                                                            tr.fps))
        if pet_only is not None:
            atomic_write_text(files.file(pet_only), format_conflicts(table.take(c["pet_only"] == 1), tr.fps))
        for path, data in pictures.items():
            atomic_write_bytes(files.file(path), data)
    typer.echo(f"wrote {out}: {n_conf} conflicts (TTC <= {ttc_s:g} s on a collision course), "
               f"{n_pet} PET-only encounters (PET <= {pet_s:g} s)"
               + (f" among {len(table)} encounters" if all_pairs else "")
               + f" in {time.perf_counter() - t0:.1f} s")
    _say_least(c)
    if review is not None and scene_dir is not None:  # (found up front with --review)
        from s2p_review.session import RecordOptions, Targets, record
        from seg2pose.io.scene import load_scene

        res = record(load_scene(scene_dir), [tracks], Targets(rrd=review, force=force),
                     RecordOptions(conflicts=out))
        typer.echo(f"wrote {res.rrd}; open it with:  rerun {res.rrd}")
