"""Many recordings at once: the steps of the single-scene commands over every scene of a study
folder, on Ray when it is installed (locally, or on a cluster by address), else serially.

Study folder layout (docs/SCALE.md)::

    STUDY/
      <scene>/            one scene folder per recording (camera device and day): scene.json,
        scene.json        ground points, masks/ or video/, optional gt/poses.csv, models/
        ...
        batch/            what ``s2p batch`` writes for this scene:
          <run>/          the run folder (poses.csv, views.csv, run.json), as ``s2p run`` writes it
          <run>.eval.json ``s2p eval --json`` of that run (scenes with ground truth)
          <run>.mcap      ``s2p export`` (+ <run>.layout.json), <run>.rrd ``s2p review -o``
          .done/<step>.json  the record that makes a re-run skip the step (see below)
      summary.json        per scene: frames, road users, errors, failures

<run> is ``baseline`` (``--baseline``) or ``s2pn`` (Seg2PoseNet models).

Every step calls the same library function its single-scene command calls, so it writes the
same files with the same atomicity (a run folder appears whole or not at all). After a step, a
record ``batch/.done/<step>.json`` holds the fingerprint of its inputs and the sha256 of its
outputs; a step whose record matches is skipped, so an interrupted study resumes where it
stopped. A step's own outputs under ``batch/`` are replaced when its inputs changed; masks a
scene already had are only replaced with ``force``.

Fault tolerance: a task whose worker dies is retried by Ray (``max_retries``); an error of the
input (S2PError or any exception) is not retried: it becomes a failure of that scene in the
summary, and the scene's later steps are skipped, the other scenes go on.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seg2pose.core.digest import file_fingerprint
from seg2pose.core.errors import InputError, S2PError
from seg2pose.core.ray import MAX_RETRIES, import_ray, start_ray
from seg2pose.io.atomic import atomic_write_text, is_temporary
from seg2pose.io.nofollow import LinkRefused, refuse_links

SUMMARY = "summary.json"
BATCH_DIR = "batch"


@dataclass(frozen=True)
class BatchOptions:
    """What the steps share: the run's method (baseline or Seg2PoseNet with models folders),
    force (also replace masks the scene had before the study ran), and segment_frames (cut
    videos longer than 1.5 segments into segments of about this many frames; 0: never)."""
    baseline: bool = True
    models: tuple[str, ...] = ()
    force: bool = False
    segment_frames: int = 0  # not in to_dict: the split gives the same masks (segments.py)

    @property
    def run_name(self) -> str:
        return "baseline" if self.baseline else "s2pn"

    def to_dict(self) -> dict:
        return {"baseline": self.baseline, "models": list(self.models), "force": self.force}


@dataclass(frozen=True)
class Step:
    """One step over a scene. inputs/outputs(scene_dir, opts) -> the files (or folders) it
    reads and writes; run(scene_dir, opts, force) -> info for the summary (JSON-ready dict,
    optionally with "frames"). A step that does not own its outputs (masks/) replaces them only
    with force or when its own record shows it made them. A step with ``parts(scene_dir, opts)
    -> [part]`` has independent pieces (video segments, each with ``frames``) run first as tasks
    of their own by ``run_part(scene_dir, part) -> info``; its ``run`` then finds them done."""
    name: str
    inputs: Callable[[Path, BatchOptions], list[Path]]
    outputs: Callable[[Path, BatchOptions], list[Path]]
    run: Callable[[Path, BatchOptions, bool], dict]
    owns_outputs: bool = True  # outputs only s2p batch writes (under batch/): replaced when stale
    parts: Callable[[Path, BatchOptions], list] | None = None
    run_part: Callable[[Path, object], dict] | None = None


# --- fingerprints ---------------------------------------------------------------------------------

def _files(p: Path) -> list[Path]:
    """The files of an output (a file, or a folder walked), without the writers' hidden
    temporaries (a killed writer's lock and partial builds are not outputs: counted as such,
    a re-run took the output for someone else's and refused to replace it)."""
    if p.is_dir():
        return sorted(q for q in p.rglob("*") if q.is_file()
                      and not any(is_temporary(n) for n in q.relative_to(p).parts))
    return [p] if p.exists() else []


def fingerprint(paths: list[Path], root: Path, extra: dict | None = None) -> dict[str, str]:
    """{relative path: sha256} of every file of ``paths`` (folders walked); ``extra`` entries
    (options) are added as they are."""
    out = {f"option:{k}": json.dumps(v, sort_keys=True) for k, v in (extra or {}).items()}
    for p in paths:
        for f in _files(Path(p)):
            out[f.relative_to(root).as_posix()] = file_fingerprint(f)
    return out


def _record_path(scene_dir: Path, step: str) -> Path:
    return scene_dir / BATCH_DIR / ".done" / f"{step}.json"


def is_complete(step: Step, scene_dir: Path, opts: BatchOptions) -> bool:
    """True when the step's record matches its current inputs and its outputs' hashes."""
    rec = _record_path(scene_dir, step.name)
    if not rec.exists():
        return False
    try:
        d = json.loads(rec.read_text())
    except (OSError, ValueError):
        return False
    outs = step.outputs(scene_dir, opts)
    if not all(Path(o).exists() for o in outs):
        return False
    return (d.get("inputs") == fingerprint(step.inputs(scene_dir, opts), scene_dir, opts.to_dict())
            and d.get("outputs") == fingerprint(outs, scene_dir))


def _write_record(step: Step, scene_dir: Path, opts: BatchOptions, inputs: dict, info: dict) -> None:
    rec = _record_path(scene_dir, step.name)
    rec.parent.mkdir(parents=True, exist_ok=True)
    outs = fingerprint(step.outputs(scene_dir, opts), scene_dir)
    atomic_write_text(rec, json.dumps({"inputs": inputs, "outputs": outs, "info": info}, indent=1))


def _refuse_linked(scene_dir: Path, step: str) -> None:
    """A scene folder of the study, its batch/ or batch/.done/ that is a link: refused before
    the step (its records and outputs would land where the link points)."""
    refuse_links(_record_path(scene_dir, step), root=scene_dir.parent)


def _started_path(scene_dir: Path, step: str) -> Path:
    return scene_dir / BATCH_DIR / ".done" / f"{step}.started"


def _may_replace(step: Step, scene_dir: Path, opts: BatchOptions) -> bool:
    """Our own earlier output (record present, or a start mark written when none of the
    step's outputs existed: a killed attempt's) may be replaced; anything else needs force."""
    if step.owns_outputs or opts.force or _record_path(scene_dir, step.name).exists():
        return True
    mark = _started_path(scene_dir, step.name)
    if mark.exists():
        return True
    if not any(_files(Path(o)) for o in step.outputs(scene_dir, opts)):
        # nothing there yet: whatever appears from now on is this step's, also when a kill
        # stops it before its record (the re-run then redoes it instead of refusing)
        mark.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(mark, time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()) + "\n")
        return True
    return False


def _failure(e: Exception) -> str:
    return str(e) if isinstance(e, S2PError) else f"{type(e).__name__}: {e}"


def attempt_part(step: Step, scene_dir: str | Path, part) -> dict:
    """Run one part of a step (a video segment); never raises for the scene's own errors."""
    t, cpu = time.perf_counter(), time.process_time()
    res: dict[str, Any] = {"scene": Path(scene_dir).name, "part": part, "status": "done", "info": {},
                           "error": None}
    assert step.run_part is not None  # only steps with parts are cut into parts
    try:
        _refuse_linked(Path(scene_dir), step.name)
        res["info"] = step.run_part(Path(scene_dir), part) or {}
        res["status"] = res["info"].get("status", "done")
    except Exception as e:  # noqa: BLE001 - reported as the scene's failure
        res["status"], res["error"] = "failed", _failure(e)
    res["seconds"], res["cpu_seconds"] = time.perf_counter() - t, time.process_time() - cpu
    return res


def attempt(step: Step, scene_dir: str | Path, opts: BatchOptions) -> dict:
    """Run one step on one scene unless it is complete. Never raises for the scene's own
    errors: returns {scene, step, status: done|skipped|failed, info, error, seconds}."""
    scene_dir = Path(scene_dir)
    t, cpu = time.perf_counter(), time.process_time()
    res: dict[str, Any] = {"scene": scene_dir.name, "step": step.name, "status": "done", "info": {},
                           "error": None}
    try:
        _refuse_linked(scene_dir, step.name)
        if is_complete(step, scene_dir, opts):
            res["status"] = "skipped"
            res["info"] = json.loads(_record_path(scene_dir, step.name).read_text()).get("info", {})
        else:
            inputs = fingerprint(step.inputs(scene_dir, opts), scene_dir, opts.to_dict())
            force = _may_replace(step, scene_dir, opts)
            res["info"] = step.run(scene_dir, opts, force) or {}
            _write_record(step, scene_dir, opts, inputs, res["info"])
    except Exception as e:  # noqa: BLE001 - a bad scene is reported, the study goes on
        res["status"] = "failed"
        res["error"] = _failure(e)
        if not any(_files(Path(o)) for o in step.outputs(scene_dir, opts)):
            # failed before writing anything: what appears later is not this step's (never
            # removed through a linked folder)
            with contextlib.suppress(LinkRefused):
                _refuse_linked(scene_dir, step.name)
                _started_path(scene_dir, step.name).unlink(missing_ok=True)
    res["seconds"], res["cpu_seconds"] = time.perf_counter() - t, time.process_time() - cpu
    return res


# --- the study ------------------------------------------------------------------------------------

def find_scenes(study: str | Path) -> list[Path]:
    """The scene folders of a study: its direct sub-folders holding scene.json, by name."""
    from seg2pose.io.scene import SCENE_FILE  # lazy: io.scene loads scipy; `s2p` imports this module at start

    study = Path(study)
    if not study.is_dir():
        raise InputError("expected a study folder (one sub-folder per scene)", file=study)
    scenes = sorted(p for p in study.iterdir() if p.is_dir() and (p / SCENE_FILE).exists())
    if not scenes:
        raise InputError(f"no scene folders (sub-folders with {SCENE_FILE})", file=study)
    return scenes


@dataclass
class StudyResult:
    """Per step, the attempts' results in scene order (``parts``: the results of its parts, e.g.
    video segments, as they finished); ``rows``: the summary's per-scene rows."""
    results: dict[str, list[dict]] = field(default_factory=dict)
    parts: dict[str, list[dict]] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)
    backend: str = "serial"
    dashboard: str | None = None
    seconds: float = 0.0

    @property
    def n_failed(self) -> int:
        return sum(1 for r in self.rows if r["failures"])


def _wave(ray, remote, fn, args: list[tuple], limit: int | None, on_done, log, what: str) -> None:
    """Run ``fn(*a)`` for every ``a`` of ``args``: as Ray tasks (``remote``), at most ``limit``
    at once, or here one after another; ``on_done(result)`` as each finishes."""
    if ray is None:
        for a in args:
            on_done(fn(*a))
        return
    pending: list[Any] = []
    queue = list(args)
    while queue or pending:
        while queue and len(pending) < (limit or len(args)):
            pending.append(remote.remote(*queue.pop(0)))
        ready, pending = ray.wait(pending, num_returns=1)
        for ref in ready:
            try:
                on_done(ray.get(ref))
            except Exception as e:  # noqa: BLE001 - retries used up: reported by the caller
                log(f"{what}: a task failed after {MAX_RETRIES} retries: {e}")


def _parts_wave(ray, remote, step: Step, scenes: list[Path], opts: BatchOptions,
                limit: int | None, progress: bool, log, results: list) -> dict[str, str]:
    """The parts of ``step`` (video segments) of every scene not complete yet, as tasks of
    their own, with a bar of frames; their results are appended to ``results``. Returns
    {scene: error} of the scenes with a failed part."""
    from dataclasses import replace

    from tqdm import tqdm

    failed: dict[str, str] = {}
    jobs = []
    for s in scenes:
        try:
            _refuse_linked(s, step.name)
            if not is_complete(step, s, opts):
                assert step.parts is not None  # only steps with parts are cut into parts
                o = replace(opts, force=_may_replace(step, s, opts))
                jobs += [(step, str(s), p) for p in step.parts(s, o)]
        except Exception as e:  # noqa: BLE001 - a bad scene is reported, the study goes on
            failed[s.name] = _failure(e)
    if not jobs:
        return failed
    bar = tqdm(total=sum(int(p.n_frames) for *_, p in jobs), desc=f"{step.name} segments",
               unit="frame", disable=not progress)
    done = {"n": 0}

    def on_done(r: dict) -> None:
        done["n"] += 1
        results.append(r)
        if r["status"] == "failed":
            failed.setdefault(r["scene"], f"segment {r['part'].camera} {r['part'].name}: {r['error']}")
        bar.set_postfix(segments=f"{done['n']}/{len(jobs)}", failed=len(failed))
        bar.update(int(r["part"].n_frames))

    _wave(ray, remote, attempt_part, jobs, limit, on_done, log, f"{step.name} segments")
    bar.close()
    if done["n"] < len(jobs):  # lost for good: the scene's own task runs what is missing
        log(f"{step.name}: {len(jobs) - done['n']} segment tasks were lost; their scenes run "
            "them in their own task")
    return failed


def run_study(study: str | Path, steps: list[Step], opts: BatchOptions, *,
              use_ray: bool = True, address: str | None = None, max_parallel: int | None = None,
              cpus: int | None = None, progress: bool = True,
              log: Callable[[str], None] = print) -> StudyResult:
    """Run ``steps`` in order over every scene of ``study``: each step is one wave of tasks
    (one per scene still without a failure; a step with parts, e.g. long videos in segments,
    first runs its parts as tasks of their own), on Ray (the cluster at ``address``, else a
    local Ray of this process's own with ``cpus`` CPUs (default: all); a Ray session this
    process started already is reused) or serially in-process. Writes STUDY/summary.json."""
    from tqdm import tqdm

    scenes = find_scenes(study)
    ray = import_ray() if use_ray else None
    if use_ray and ray is None and address is not None:
        raise S2PError("a Ray address was given but Ray is not installed: pip install 'seg2pose[scale]'")
    out = StudyResult(backend="serial")
    t0 = time.perf_counter()
    remote = remote_part = None
    if ray is not None:
        if not ray.is_initialized():
            # no address: a Ray of this command's own, never another user's cluster
            ctx = start_ray(ray, address, cpus, include_dashboard=None, log_to_driver=False)
            out.dashboard = getattr(ctx, "dashboard_url", None) or None
        out.backend = "ray"
        if out.dashboard:
            log(f"Ray dashboard: http://{out.dashboard}")
        remote = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(attempt)
        remote_part = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(attempt_part)
    failed: set[str] = set()
    for step in steps:
        todo = [s for s in scenes if s.name not in failed]
        results: dict[str, dict] = {}
        if step.parts is not None:
            out.parts[step.name] = []
            for name, err in _parts_wave(ray, remote_part, step, todo, opts, max_parallel,
                                         progress, log, out.parts[step.name]).items():
                results[name] = {"scene": name, "step": step.name, "status": "failed", "info": {},
                                 "error": err, "seconds": 0.0}
        bar = tqdm(total=len(todo), desc=step.name, unit="scene", disable=not progress)
        frames = 0

        def done(r: dict) -> None:
            nonlocal frames
            results[r["scene"]] = r
            frames += int(r["info"].get("frames", 0) or 0)
            bar.set_postfix(frames=frames, failed=sum(x["status"] == "failed" for x in results.values()))
            bar.update(1)

        _wave(ray, remote, attempt, [(step, s if ray is None else str(s), opts)
                                     for s in todo if s.name not in results],
              max_parallel, done, log, step.name)
        for s in todo:  # a task lost for good (its worker died every time)
            if s.name not in results:
                results[s.name] = {"scene": s.name, "step": step.name, "status": "failed",
                                   "info": {}, "error": "the task's worker died on every retry",
                                   "seconds": 0.0}
        bar.close()
        out.results[step.name] = [results[s.name] for s in todo]
        failed |= {n for n, r in results.items() if r["status"] == "failed"}
    out.seconds = time.perf_counter() - t0
    out.rows = summary_rows(scenes, out.results)
    write_summary(Path(study), out, [s.name for s in steps], opts)
    return out


def summary_rows(scenes: list[Path], results: dict[str, list[dict]]) -> list[dict]:
    """Per scene: frames, road users, mean error (where ground truth exists), failures, and
    each step's status."""
    rows = []
    for s in scenes:
        row: dict[str, Any] = {"scene": s.name, "frames": None, "road_users": None, "mean_error_m": None,
               "recall": None, "steps": {}, "failures": []}
        for step, rs in results.items():
            r = next((x for x in rs if x["scene"] == s.name), None)
            if r is None:
                row["steps"][step] = "not run"
                continue
            row["steps"][step] = r["status"]
            info = r["info"]
            if r["status"] == "failed":
                row["failures"].append({"step": step, "error": r["error"]})
            if "frames" in info:
                row["frames"] = info["frames"]
            if "road_users" in info:
                row["road_users"] = info["road_users"]
            if "mean_error" in info:
                row["mean_error_m"], row["recall"] = info["mean_error"], info.get("recall")
            if "seams" in info:  # long videos in segments: the stitch's id changes per border
                row["segments"], row["seams"] = info["segments"], info["seams"]
                row["seam_id_changes"] = info["seam_id_changes"]
                row["seam_unlinked"] = info.get("seam_unlinked", 0)
        rows.append(row)
    return rows


def write_summary(study: Path, res: StudyResult, steps: list[str], opts: BatchOptions) -> Path:
    p = study / SUMMARY
    atomic_write_text(p, json.dumps({"steps": steps, "options": opts.to_dict(),
                                     "backend": res.backend, "seconds": round(res.seconds, 3),
                                     "scenes": res.rows}, indent=1))
    return p


def format_summary(rows: list[dict]) -> str:
    """The study table: one line per scene."""
    def f(v, fmt="{}"):
        return "-" if v is None else fmt.format(v)

    lines = [f"{'scene':<20} {'frames':>7} {'road users':>10} {'error m':>8}  failures"]
    for r in rows:
        fails = "; ".join(f"{x['step']}: {x['error']}" for x in r["failures"]) or "-"
        lines.append(f"{r['scene']:<20} {f(r['frames']):>7} {f(r['road_users']):>10} "
                     f"{f(r['mean_error_m'], '{:.3f}'):>8}  {fails}")
    return "\n".join(lines)
