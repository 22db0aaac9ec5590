"""Long videos in segments: one camera's masks-from-video (background subtraction, then the
tracker) cut into frame ranges that run as independent tasks and are stitched back into the
one MOTS file ``s2p masks-from-video`` writes, so that one long video uses a whole cluster.

Plan (``plan_segments``): a camera's N frames are cut into round(N / ``segment_frames``) equal
segments (a video shorter than 1.5 segments is not cut). Segment i *owns* frames [a_i, b_i) and
*reads* from a_i - ``overlap`` (its warm-up): its background model starts from the uncut run's
starting background (the same samples from the video's start) and follows the frames of the
warm-up as the uncut one followed the frames before, so that both agree at the border, and the
tracker meets the road users present there.
The default overlap, 2 (max_gap + min_length) frames of the tracker's settings (and a history
of frames when the background model starts empty, ``init: none``), lets a road user lost for
up to max_gap frames around the border be seen by both segments.

A segment (``run_segment``): ``masks_from_video`` over the frames it reads, then the tracker
with every track kept (a track cut by the segment's end may be short here and long overall),
written to ``SCENE/batch/segments/<camera>/<first>-<last>.txt`` as one atomic file (a killed
task leaves nothing under that name), then its record ``<first>-<last>.json`` (fingerprint of
the video, scene and settings; sha256 of the file). A re-run skips segments whose record holds.

Stitch (``stitch_camera``), streamed, segment by segment: in the later half of each overlap
(where the later segment's background and tracker have settled) both segments' masks are
matched frame by frame (IoU >= 0.5, Hungarian); pairs of tracks matched in at least half of the
frames both are seen are linked (Hungarian on those counts, ``linear_sum_assignment``), so a
road user keeps its id across the border; the later segment's other tracks get new ids.
Warm-up frames are dropped; tracks with fewer than ``min_length`` masks are dropped and ids
renumbered in order of first appearance, as the single run's tracker does; fragment tracks are
joined and size classes follow as in ``s2p masks-from-video``. The split can differ from the
single run only near a border; the stitch counts, per border, the road users whose id changes
there (``id_changes``: masks matched at the last frame both segments hold, whose tracks were not
linked).
"""

from __future__ import annotations

import hashlib
import json
from collections import defaultdict
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from seg2pose.core.digest import file_fingerprint, file_sha256
from seg2pose.core.errors import InputError
from seg2pose.io.atomic import atomic_write_text, check_writable, replacing
from seg2pose.io.mots import MaskTable, iter_mots, write_mots
from seg2pose.io.scene import SCENE_FILE, Scene, load_scene
from seg2pose.io.track_ids import stage_ids
from seg2pose.io.video import image_files
from seg2pose.structures.masks import iou
from seg2pose.video.classify import classify_mots, size_rules
from seg2pose.video.fragments import join_fragments
from seg2pose.video.track import TrackConfig, track_mots
from seg2pose.video.video_masks import BgConfig, masks_from_video
from seg2pose.video.video_scene import associate_step, camera_reader, masks_outputs, scene_masks_from_video

SEGMENTS_DIR = "batch/segments"
LINK_IOU = 0.5  # masks of the two segments in an overlap frame are the same road user above this


@dataclass(frozen=True)
class Segment:
    """A camera's frame range (scene frames, inclusive): ``first``..``last`` owned,
    ``read_from``..``last`` read (warm-up first), ``match_from``..``first``-1 where the stitch
    matches it to the segment before; ``n_frames`` owned, ``n_warm`` of warm-up."""
    camera: str
    index: int
    first: int
    last: int
    read_from: int
    match_from: int
    n_frames: int
    n_warm: int = 0

    @property
    def name(self) -> str:
        return f"{self.first:08d}-{self.last:08d}"


def plan_segments(frames: np.ndarray, segment_frames: int, overlap: int, camera: str = ""
                  ) -> list[Segment]:
    """Segments of a camera whose scene frames are ``frames`` (N,) sorted: round(N /
    segment_frames) equal ones (one when ``segment_frames`` <= 0 or N < 1.5 segments)."""
    n = len(frames)
    k = max(1, round(n / segment_frames)) if segment_frames > 0 and n else 1
    cuts = np.linspace(0, n, k + 1).round().astype(np.int64)
    out = []
    for i, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        if b <= a:
            continue
        r = max(0, a - overlap)
        out.append(Segment(camera, i, int(frames[a]), int(frames[b - 1]), int(frames[r]),
                           int(frames[max(r, a - (overlap + 1) // 2)]) if a else int(frames[a]),
                           int(b - a), int(a - r)))
    return out


def settings(scene: Scene) -> tuple[BgConfig, TrackConfig]:
    """The scene's background-subtraction and tracker settings (scene.json ``extra``)."""
    sj = scene.root / SCENE_FILE
    return (BgConfig.from_dict(scene.extra.get("video_masks") or {}, file=sj),
            TrackConfig.from_dict(scene.extra.get("tracker") or {}, file=sj))


def default_overlap(bg: BgConfig, tcfg: TrackConfig) -> int:
    """Frames of warm-up before each border (module docstring)."""
    return max(2 * (tcfg.max_gap + tcfg.min_length), 3 * bg.history)


def camera_frames(scene: Scene, camera: str) -> np.ndarray:
    """The scene frames (N,) of a camera's video; empty when its header gives no frame count."""
    reader = camera_reader(scene, camera)
    if reader.is_folder:
        return np.array([f for f, _ in image_files(reader.path)], np.int64)
    _, _, n = reader.header()
    return reader.frame_numbers(n)


def plan_scene(scene_dir: str | Path, segment_frames: int, overlap: int | None = None
               ) -> dict[str, list[Segment]]:
    """Per camera of the scene: its segments (one = not cut)."""
    scene = load_scene(scene_dir)
    bg, tcfg = settings(scene)
    ov = default_overlap(bg, tcfg) if overlap is None else int(overlap)
    return {c: plan_segments(camera_frames(scene, c), segment_frames, ov, c) for c in scene.cameras}


def segment_path(scene_dir: Path, seg: Segment) -> Path:
    return Path(scene_dir) / SEGMENTS_DIR / seg.camera / f"{seg.name}.txt"


def _video_digest(path: Path) -> str:
    if path.is_dir():  # an image folder: its listing (names, sizes, times), not every image
        h = hashlib.sha256()
        for _f, p in image_files(path):
            st = p.stat()
            h.update(f"{p.name} {st.st_size} {st.st_mtime_ns}\n".encode())
        return h.hexdigest()
    return file_fingerprint(path)


def _inputs(scene: Scene, seg: Segment, bg: BgConfig, tcfg: TrackConfig) -> dict:
    files = [scene.root / SCENE_FILE, scene.root / "ground_points.csv"]
    return {"segment": asdict(seg), "video_masks": bg.to_dict(), "tracker": tcfg.to_dict(),
            "video": _video_digest(camera_reader(scene, seg.camera).path),
            **{p.name: file_sha256(p) for p in files if p.exists()}}


def segment_done(scene_dir: str | Path, seg: Segment, inputs: dict | None = None) -> dict | None:
    """The info of a finished segment whose record matches (None if it must run)."""
    out = segment_path(Path(scene_dir), seg)
    rec = out.with_suffix(".json")
    if not out.exists() or not rec.exists():
        return None
    try:
        d = json.loads(rec.read_text())
    except (OSError, ValueError):
        return None
    if inputs is None:
        scene = load_scene(scene_dir)
        inputs = _inputs(scene, seg, *settings(scene))
    if d.get("inputs") != inputs or d.get("output") != file_sha256(out):
        return None
    return d.get("info") or {}


def run_segment(scene_dir: str | Path, seg: Segment, log: Callable[[str], None] = lambda s: None
                ) -> dict:
    """Masks and tracks of one segment (module docstring), unless its record says it is done.
    Returns its info: frames (owned, read), masks, stopped (why the video ended early), status."""
    scene = load_scene(scene_dir)
    bg, tcfg = settings(scene)
    inputs = _inputs(scene, seg, bg, tcfg)
    done = segment_done(scene.root, seg, inputs)
    if done is not None:
        return {**done, "status": "skipped"}
    reader = camera_reader(scene, seg.camera)
    out = segment_path(scene.root, seg)
    # masks, then tracks, in a partial folder of its own (a killed task's is removed by the
    # next), swapped in when both are done: all or nothing
    with replacing(out, force=True, folder=False) as tmp:
        res = masks_from_video(reader.path, tmp, bg, camera=scene.cameras[seg.camera],
                               first_frame=reader.first, frame_step=reader.step,
                               frames=(seg.read_from, seg.last), log=log,
                               init_from=reader.first)  # the uncut run's starting background
        track_mots(tmp, tmp, scene.cameras[seg.camera], scene.ground, replace(tcfg, min_length=1),
                   log=log)
    info = {"frames": seg.n_frames, "read": res.n_frames, "masks": res.n_masks,
            "last_good": res.last_good, "stopped": res.stopped,
            "unsettled": [r for r in res.unsettled if r[1] >= seg.first]}
    atomic_write_text(out.with_suffix(".json"),
                      json.dumps({"inputs": inputs, "output": file_sha256(out), "info": info}, indent=1))
    return {**info, "status": "done"}


def _link(tail: list[tuple[int, MaskTable]], head: list[tuple[int, MaskTable]]
          ) -> tuple[dict[int, int], int]:
    """Links between the earlier segment's tracks (``tail``: its last frames, global ids) and
    the later one's (``head``: its warm-up frames, local ids) -> ({local id: global id}, road
    users whose id changes at the last frame both hold: matched masks of unlinked tracks)."""
    before = dict(tail)
    votes: dict[tuple[int, int], int] = defaultdict(int)
    seen_a: dict[int, int] = defaultdict(int)
    seen_b: dict[int, int] = defaultdict(int)
    last_pairs: list[tuple[int, int]] = []
    for f, tb in head:
        for t in tb.track_id.tolist():
            seen_b[t] += 1
        ta = before.get(f)
        if ta is None or not len(ta) or not len(tb):
            continue
        m = iou(ta.rles, tb.rles, ta.height, ta.width)
        r, c = linear_sum_assignment(-m)
        ok = m[r, c] >= LINK_IOU
        pairs = list(zip(ta.track_id[r[ok]].tolist(), tb.track_id[c[ok]].tolist()))
        for p in pairs:
            votes[p] += 1
        last_pairs = pairs
    both = {f for f, _ in head}
    for f, ta in tail:
        if f in both:
            for t in ta.track_id.tolist():
                seen_a[t] += 1
    links: dict[int, int] = {}
    if votes:
        a_ids = sorted({a for a, _ in votes})
        b_ids = sorted({b for _, b in votes})
        v = np.zeros((len(a_ids), len(b_ids)))
        for (a, b), n in votes.items():
            v[a_ids.index(a), b_ids.index(b)] = n
        for i, j in zip(*linear_sum_assignment(-v)):
            a, b = a_ids[i], b_ids[j]
            if v[i, j] > 0 and v[i, j] >= 0.5 * min(seen_a[a], seen_b[b]):
                links[b] = a
    changes = sum(1 for a, b in last_pairs if links.get(b) != a)
    return links, changes


def _seam(tail, head, seg: Segment, last_seen: dict[int, int], max_gap: int, seams: list) -> dict:
    """Links at the border before ``seg``, and its entry in ``seams``: tracks linked, id
    changes (certain ones, see ``_link``) and ``unlinked``: tracks of the earlier segment seen
    within max_gap frames of the border and not continued (an id change if the road user
    reappears after the border, e.g. from behind an occlusion; nothing if it left)."""
    m, changes = _link(tail, head)
    linked = set(m.values())
    unlinked = sum(1 for g, f in last_seen.items() if f >= seg.first - max_gap and g not in linked)
    seams.append({"border": seg.first, "linked": len(m), "id_changes": changes,
                  "unlinked": unlinked})
    return m


def stitch_camera(scene: Scene, segs: list[Segment], out: Path, tcfg: TrackConfig,
                  log: Callable[[str], None] = print) -> dict:
    """The segments' files as one MOTS file ``out`` (atomic) with ids continued across the
    borders (module docstring). Returns frames, masks, tracks and the seams."""
    max_gap = tcfg.max_gap
    files = [segment_path(scene.root, s) for s in segs]
    done = [segment_done(scene.root, s) for s in segs]
    missing = [s.name for s, i in zip(segs, done) if i is None]
    if missing:
        raise InputError(f"segments {missing} of camera {segs[0].camera} are not finished",
                         file=files[0].parent)
    infos = [i for i in done if i is not None]  # every segment's (none missing)
    # a video that ended early ends the camera's frames there, as in the single run
    end = len(segs)
    for k, i in enumerate(infos):
        if i.get("stopped") and (i.get("last_good") is None or i["last_good"] < segs[k].last):
            end = k + 1
            log(f"warning: {segs[k].camera}: {i['stopped']}; kept the masks up to frame "
                f"{i.get('last_good')}")
            break
    segs, files = segs[:end], files[:end]
    maps: list[dict[int, int]] = []
    count: dict[int, int] = {}
    order: list[int] = []
    seams: list[dict] = []
    last_seen: dict[int, int] = {}  # global id -> last frame with a mask
    next_gid = 1
    tail: list[tuple[int, MaskTable]] = []
    for k, (s, f) in enumerate(zip(segs, files)):
        keep_from = segs[k + 1].match_from if k + 1 < len(segs) else None
        head: list[tuple[int, MaskTable]] = []
        m: dict[int, int] | None = {} if k == 0 else None
        new_tail = []
        for frame, t in iter_mots(f, check_rles=False):
            if frame < s.first:  # warm-up
                if frame >= s.match_from:
                    head.append((frame, t))
                continue
            if m is None:
                m = _seam(tail, head, s, last_seen, max_gap, seams)
            gids = []
            for t_id in t.track_id.tolist():
                if t_id not in m:
                    m[t_id], next_gid = next_gid, next_gid + 1
                g = m[t_id]
                gids.append(g)
                if g not in count:
                    count[g] = 0
                    order.append(g)
                count[g] += 1
                last_seen[g] = frame
            if keep_from is not None and frame >= keep_from:
                new_tail.append((frame, MaskTable(t.frame, np.array(gids, np.int64), t.class_id,
                                                  t.height, t.width, t.rles)))
        if m is None:  # no owned frame with masks
            m = _seam(tail, head, s, last_seen, max_gap, seams)
        maps.append(m)
        tail = new_tail
    kept = [g for g in order if count[g] >= max(tcfg.min_length, 1)]
    final = {g: i + 1 for i, g in enumerate(kept)}
    n_masks = {"n": 0}

    def rows():
        for s, f, m in zip(segs, files, maps):
            for _, t in iter_mots(f, frame_range=(s.first, s.last), check_rles=False):
                ids = np.array([final.get(m[i], -1) for i in t.track_id.tolist()], np.int64)
                t.track_id = ids
                keep = ids >= 0
                if keep.any():
                    n_masks["n"] += int(keep.sum())
                    yield t.take(keep)

    write_mots(out, rows())
    frames = sum(max(0, int(i.get("read", 0)) - s.n_warm) for s, i in zip(segs, infos))
    return {"frames": frames, "masks": n_masks["n"], "tracks": len(kept), "segments": len(segs),
            "seams": seams}


def scene_masks_segmented(scene_dir: str | Path, segment_frames: int, *, overlap: int | None = None,
                          force: bool = False, map_segments=None, progress: bool = False,
                          log: Callable[[str], None] = print) -> dict[str, dict]:
    """masks/<camera>.txt of every camera, as ``scene_masks_from_video`` writes them, with
    videos longer than 1.5 ``segment_frames`` cut into segments. ``map_segments(fn, segs)``
    runs the segments (default: one after another; finished ones are skipped). Returns per
    camera: frames, masks, tracks, segments, seams."""
    scene = load_scene(scene_dir)
    plans = plan_scene(scene.root, segment_frames, overlap)
    _, tcfg = settings(scene)
    out = {}
    whole = [c for c, segs in plans.items() if len(segs) <= 1]
    cut = [c for c in plans if c not in whole]
    for c in plans:  # every camera refused up front, before any work
        check_writable(scene.masks_path(c), force)
    if whole:
        res = scene_masks_from_video(scene.root, whole, force=force, progress=progress,
                                     associate=False, log=log)
        for c, r in res.items():
            out[c] = {"frames": r.n_frames, "masks": r.n_masks, "segments": 1, "seams": []}
    built = {}
    with masks_outputs(scene, cut, force) as files:
        for c in cut:
            segs = plans[c]
            list((map_segments or map)(lambda s: run_segment(scene.root, s, log), segs))
            dst = scene.masks_path(c)
            tmp = files.file(dst)  # stitched, then classified, then swapped in
            info = stitch_camera(scene, segs, tmp, tcfg, log=log)
            rules = size_rules(scene.classes, scene.extra, file=scene.root / SCENE_FILE)
            join_fragments(tmp, tmp, scene.cameras[c], scene.ground, rules, scene.fps, tcfg,
                           log=log)  # as masks-from-video does, over the stitched tracks
            classify_mots(tmp, tmp, scene.cameras[c], scene.ground, rules, fps=scene.fps, log=log)
            built[c] = tmp
            log(f"{c}: {info['frames']} frames in {info['segments']} segments -> {info['tracks']} "
                f"tracks ({info['masks']} masks); at the seams: "
                f"{sum(x['id_changes'] for x in info['seams'])} id changes, "
                f"{sum(x['unlinked'] for x in info['seams'])} tracks not continued")
            out[c] = info
        if cut:  # the cut cameras' masks and their record, swapped in together
            stage_ids(files, scene.root / "masks", {c: "tracker" for c in cut}, built)
    associate_step(scene, [], True, log)
    return out
