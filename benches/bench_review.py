"""Benchmark: write a review recording (.rrd) of a 1,000-frame, 3-camera, 20-road-user run with
masks, once with column logging (``s2p_review.record``: rr.send_columns over whole frame
ranges) and once with one ``rr.log`` call per entity per frame (the naive way).

Prints seconds, MB/s and .rrd bytes per frame for both, the speed-up, and peak memory; the
entities of the recording, the recording's CPU time, how long reading it back takes, and with
``--viewer`` how long a headless viewer takes to load it (wall and the viewer's CPU).

    .venv/bin/python benches/bench_review.py [--frames 1000] [--width 640] [--height 360]
        [--track-frames N] [--skip-per-frame] [--viewer [--viewer-loads N]]

``--track-frames 50`` gives every road user a new track id every 50 frames (road users coming
and going: 400 tracks instead of 20), the case one entity per road user costs most in.

The scene is built once (masks rendered from boxes with cv2) and cached under the system temp
folder; building it is not timed.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def build_scene(root: Path, n_frames: int, n_users: int, width: int, height: int, seed: int = 0,
                track_frames: int = 0):
    """A 3-camera junction with n_users road users driving straight lines (wrapping around);
    track_frames > 0: each road user takes a new track id every track_frames frames (road users
    coming and going: n_users * n_frames / track_frames tracks), else one track each."""
    import cv2

    from s2p_review.columns import box_corners
    from seg2pose.geometry.camera import Camera, Rig
    from seg2pose.geometry.normal import normal_positions
    from seg2pose.io.mots import MaskTable, write_mots
    from seg2pose.io.poses import PoseTable, write_poses
    from seg2pose.io.run import ViewTable, relative_path, write_run_folder
    from seg2pose.io.scene import DEFAULT_CLASSES, ClassSpec, Scene, load_scene
    from seg2pose.structures.masks import encode, mask_centers

    marker = root / "built.json"
    want = {"n_frames": n_frames, "n_users": n_users, "w": width, "h": height, "seed": seed, "v": 2,
            "track_frames": track_frames}
    if marker.exists() and json.loads(marker.read_text()) == want:
        return load_scene(root), root / "run"
    shutil.rmtree(root, ignore_errors=True)
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.linspace(-30, 30, 7), np.linspace(-30, 30, 7))
    pts = np.stack([gx.ravel(), gy.ravel(), 0.01 * gx.ravel() + 0.005 * gy.ravel()], axis=1)
    f = 0.8 * width
    cams = {f"c{i}": Camera.look_at(f"c{i}", [30 * np.cos(a), 30 * np.sin(a), 10.0], [0, 0, 0], f,
                                    width, height)
            for i, a in enumerate(np.deg2rad([-90, 30, 150]))}
    scene = Scene(root=root, name="bench", fps=10.0, rig=Rig(cams, {"tri": list(cams)}),
                  ground_points=pts, classes=[ClassSpec(**c) for c in DEFAULT_CLASSES])
    scene.save(root)
    scene = load_scene(root)
    sizes = {"pedestrian": (0.6, 0.6, 1.75), "bicyclist": (1.8, 0.6, 1.75), "car": (4.5, 1.8, 1.5)}
    cls = rng.choice(["pedestrian", "bicyclist", "car"], n_users)
    speed = np.array([{"pedestrian": 0.14, "bicyclist": 0.4, "car": 0.9}[c] for c in cls])
    ang = rng.uniform(0, 2 * np.pi, n_users)
    start = rng.uniform(-15, 15, (n_users, 2))
    fr = np.repeat(np.arange(n_frames), n_users)
    uid = np.tile(np.arange(n_users), n_frames)
    s = (fr * speed[uid]) % 40 - 20  # position along the line, wrapping inside the junction
    xy = start[uid] * 0.3 + s[:, None] * np.stack([np.cos(ang[uid]), np.sin(ang[uid])], 1)
    z = scene.ground.height(xy)
    size = np.array([sizes[c] for c in cls[uid]])
    tid = uid + 1 if track_frames <= 0 else (fr // track_frames) * n_users + uid + 1
    gt = PoseTable(fr, tid, cls[uid], np.c_[xy, z], ang[uid], size)
    (root / "gt").mkdir(exist_ok=True)
    write_poses(root / "gt" / "poses.csv", gt)
    cid = {"pedestrian": 1, "bicyclist": 2, "car": 3}
    views = []
    for name, cam in scene.cameras.items():
        corners = box_corners(gt.xyz, gt.heading, gt.size)
        uv, _, front = cam.project_points(corners.reshape(-1, 3))
        uv = uv.reshape(-1, 8, 2)
        ok = front.reshape(-1, 8).all(1) & cam.in_image(uv.reshape(-1, 2)).reshape(-1, 8).any(1)
        keep, rles = [], []
        m = np.zeros((height, width), np.uint8)
        for i in np.flatnonzero(ok):
            m[:] = 0
            cv2.fillConvexPoly(m, cv2.convexHull(np.round(uv[i] - 0.5).astype(np.int32)), 1)
            if m.any():
                keep.append(i)
                rles.append(encode(m))
        keep = np.array(keep)
        mt = MaskTable(gt.frame[keep], gt.track_id[keep], [cid[c] for c in gt.cls[keep]], height, width, rles)
        write_mots(scene.masks_path(name), mt)
        c = mask_centers(rles, height, width)
        hts = np.array([0.9 if k != "car" else 0.75 for k in gt.cls[keep]])
        xn, _ = normal_positions(cam, scene.ground, c, hts)
        xn = np.nan_to_num(xn)
        views.append(ViewTable(gt.frame[keep], gt.track_id[keep], [name] * len(keep), gt.cls[keep],
                               c, xn, np.tile([0.1, -0.1], (len(keep), 1))))
    run = root / "run"
    est = PoseTable(gt.frame, gt.track_id, gt.cls, gt.xyz + rng.normal(0, 0.3, gt.xyz.shape) * [1, 1, 0],
                    gt.heading, gt.size)
    write_run_folder(run, est, ViewTable.concat(views),
                     {"scene": relative_path(root, run), "cameras": list(cams), "method": "seg2posenet"})
    marker.write_text(json.dumps(want))
    return load_scene(root), run


def log_per_frame(scene, run_dir: Path, rrd: Path) -> None:
    """The same content as ``record``, one rr.log per entity per frame."""
    import rerun as rr

    from s2p_review import columns as C
    from s2p_review import layout as L
    from s2p_review.columns import sizes_of as _with_size
    from s2p_review.recording import LogContext, log_static
    from s2p_review.runs import load_run
    from s2p_review.timebase import scene_timebase
    from seg2pose.eval.evaluate import per_frame_errors
    from seg2pose.io.mots import iter_mots
    from seg2pose.io.poses import read_poses

    run = load_run(run_dir, scene)
    gt = read_poses(scene.gt_path)
    cams = list(scene.cameras)
    rec = rr.RecordingStream("s2p-bench")
    rec.save(rrd, default_blueprint=L.blueprint(cams, [run.name]))
    log_static(LogContext(rec, scene, scene_timebase(scene), 0, 0), cams)
    poses, v = run.poses, run.views
    psz, gsz = _with_size(poses, scene), _with_size(gt, scene)
    frames = np.arange(int(poses.frame.min()), int(poses.frame.max()) + 1)
    pf = {f: np.flatnonzero(poses.frame == f) for f in frames}
    gf = {f: np.flatnonzero(gt.frame == f) for f in frames}
    streams = {c: iter(iter_mots(scene.masks_path(c))) for c in cams}
    pending = {c: next(streams[c], None) for c in cams}
    ef, emean, _ = per_frame_errors(poses, gt)
    err = dict(zip(ef.tolist(), emean.tolist()))
    trails = C.trail_strips(poses.track_id, poses.frame, poses.xyz, L.TRAIL_FRAMES)
    for f in frames:
        rec.set_time(L.TIMELINE, sequence=int(f))
        rec.set_time(L.TIME, duration=f / scene.fps)
        i, g = pf[f], gf[f]
        t = poses.take(i)
        rec.log(f"world/road_users/{run.name}", rr.Boxes3D(
            **C.box_columns(t.xyz, t.heading, psz[i]), colors=L.class_colors(t.cls, scene.classes),
            labels=L.labels(t.cls, t.track_id)))
        rec.log(f"world/road_users/{run.name}/trails", rr.LineStrips3D([trails[k] for k in i]))
        rec.log("world/gt", rr.Boxes3D(**C.box_columns(gt.xyz[g], gt.heading[g], gsz[g]),
                                       colors=L.GT_COLOR))
        if f in err:
            rec.log(f"metrics/error/{run.name}/mean", rr.Scalars(err[f]))
        for c in cams:
            cam = scene.cameras[c]
            p = pending[c]
            rles, vals = [], np.zeros(0, np.int64)
            if p is not None and p[0] == f:
                rles, vals = p[1].rles, p[1].class_id
                pending[c] = next(streams[c], None)
            img = C.paint_masks(rles, vals, np.zeros(len(rles), np.int64), cam.height, cam.width, 1)[0]
            rec.log(f"{L.cam_path(c)}/masks", rr.SegmentationImage(img))
            segs, _ = C.projected_paths(cam, t.xyz, t.heading, psz[i])
            rec.log(f"{L.cam_path(c)}/poses/{run.name}", rr.LineStrips2D(segs))
            sel = (v.frame == f) & (v.camera == c)
            rec.log(f"{L.cam_path(c)}/normal/{run.name}", rr.Points2D(v.uv[sel]))
            rec.log(f"world/estimates/{run.name}/{c}", rr.Points3D(v.normal[sel]))
            rec.log(f"world/estimates/{run.name}/{c}/residuals",
                    rr.Arrows3D(origins=v.normal[sel], vectors=np.c_[v.residual[sel], np.zeros(sel.sum())]))
    rec.flush()
    rec.disconnect()


def _proc_cpu(pid: int) -> float:
    """User + system CPU seconds so far of process ``pid`` and its descendants (the `rerun`
    command is a launcher whose child is the viewer; Linux /proc)."""
    import os

    stats = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                f = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            stats[int(d.name)] = (int(f[1]), int(f[11]) + int(f[12]))  # ppid, utime + stime
    tree, todo = set(), [pid]
    while todo:
        p = todo.pop()
        tree.add(p)
        todo += [c for c, (pp, _) in stats.items() if pp == p and c not in tree]
    return sum(stats[p][1] for p in tree if p in stats) / os.sysconf("SC_CLK_TCK")


def load_times(rrd: Path, last_frame: int, viewer: bool, loads: int = 1) -> dict:
    """Seconds to read every chunk of ``rrd`` back (rerun.chunk) and, with ``viewer``, for a
    headless viewer to open it until its frame timeline reaches ``last_frame`` with nothing
    loading (polled every 20 ms; wall time and the viewer's CPU time: the median and the least
    of ``loads`` loads, each by a fresh viewer); also the number of entities with data."""
    import statistics

    import rerun.chunk as rc

    t = time.perf_counter()
    entities = {ch.entity_path for ch in rc.RrdReader(rrd).stream()}
    out = {"read_s": time.perf_counter() - t, "entities": len(entities)}
    if viewer:
        runs = [viewer_load(rrd, last_frame) for _ in range(max(1, loads))]
        for k in ("viewer_s", "viewer_cpu_s"):
            out[k] = statistics.median(r[k] for r in runs)
            out[k.replace("_s", "_min_s")] = min(r[k] for r in runs)
    return out


def viewer_load(rrd: Path, last_frame: int) -> dict:
    """One load of ``rrd`` by a fresh headless viewer (nothing cached from a load before; see
    ``load_times``): wall seconds and the viewer's CPU seconds."""
    from s2p_review import viewer as V

    client = V.spawn_viewer(headless=True)
    try:
        cpu0 = _proc_cpu(client._pid)
        t = time.perf_counter()
        client.open(str(rrd.resolve()))
        while True:
            st = client.get_state()
            rec = next((r for r in st.recordings if r.store_id == st.active_recording), None)
            tl = None if rec is None else next((x for x in rec.timelines if x.name == "frame"), None)
            if tl is not None and tl.end is not None and tl.end >= last_frame and not st.loading:
                break
            if time.perf_counter() - t > 300:
                raise RuntimeError("the viewer did not load the recording within 300 s")
            time.sleep(0.02)
        return {"viewer_s": time.perf_counter() - t, "viewer_cpu_s": _proc_cpu(client._pid) - cpu0}
    finally:
        V.stop(client)


def _time_rerun_calls() -> dict:
    """Wrap RecordingStream.log / send_columns / flush to add up the time spent inside them."""
    import rerun as rr

    acc = {"s": 0.0}

    def wrap(fn):
        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                acc["s"] += time.perf_counter() - t
        return timed

    for name in ("log", "send_columns", "flush"):
        setattr(rr.RecordingStream, name, wrap(getattr(rr.RecordingStream, name)))
    return acc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--users", type=int, default=20)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--track-frames", type=int, default=0,
                    help="a new track id every N frames per road user (0: one track each)")
    ap.add_argument("--skip-per-frame", action="store_true")
    ap.add_argument("--viewer", action="store_true",
                    help="also time a headless viewer loading the .rrd (needs Vulkan, e.g. Mesa)")
    ap.add_argument("--viewer-loads", type=int, default=1,
                    help="with --viewer: loads to time (median and least reported)")
    a = ap.parse_args()
    import rerun  # noqa: F401 - imported before timing: both ways pay it once per process

    from s2p_review.session import RecordOptions, record

    cache = Path(tempfile.gettempdir()) / f"s2p-bench-review-{a.frames}-{a.users}-{a.width}x{a.height}-{a.track_frames}"
    t0 = time.perf_counter()
    scene, run = build_scene(cache, a.frames, a.users, a.width, a.height, track_frames=a.track_frames)
    print(f"scene: {a.frames} frames, 3 cameras {a.width}x{a.height}, {a.users} road users "
          f"(built/loaded in {time.perf_counter() - t0:.1f} s, cached in {cache})")
    out = Path(tempfile.mkdtemp(prefix="s2p-bench-"))
    results = {}
    timer = _time_rerun_calls()
    timer["s"] = 0.0
    t, cpu = time.perf_counter(), time.process_time()
    record(scene, [run], out / "columns.rrd", RecordOptions(mask_every=1))
    results["columns (send_columns)"] = (time.perf_counter() - t, timer["s"], (out / "columns.rrd").stat().st_size)
    record_cpu = time.process_time() - cpu
    loads = load_times(out / "columns.rrd", a.frames - 1, a.viewer, a.viewer_loads)
    if not a.skip_per_frame:
        timer["s"] = 0.0
        t = time.perf_counter()
        log_per_frame(scene, run, out / "per_frame.rrd")
        results["per-frame rr.log"] = (time.perf_counter() - t, timer["s"], (out / "per_frame.rrd").stat().st_size)
    raw = a.frames * 3 * a.width * a.height  # mask bytes logged (uint8 class ids)
    print("whole recording = reading the scene and run, decoding masks, building arrays, and the "
          "Rerun calls;\nRerun calls = time inside log / send_columns / flush only")
    for k, (sec, rr_sec, size) in results.items():
        print(f"{k:24s} whole {sec:6.2f} s  Rerun calls {rr_sec:6.2f} s  {size / 1e6 / sec:6.1f} MB/s "
              f"written  {raw / 1e6 / sec:6.1f} MB/s of masks  {size / a.frames / 1e3:6.1f} kB/frame "
              f"({size / 1e6:.1f} MB .rrd)")
    if len(results) == 2:
        (c, cr, _), (p, pr, _) = results.values()
        print(f"speed-up columns vs per-frame: whole recording {p / c:.1f}x, Rerun calls {pr / cr:.1f}x")
    print(f"columns.rrd: {loads['entities']} entities; recording {record_cpu:.2f} s CPU (this process: "
          f"less sensitive to other load than the wall time); read back (rerun.chunk.RrdReader, all "
          f"chunks) {loads['read_s']:.2f} s" + (
              f"; headless viewer open -> loaded (median of {a.viewer_loads}, least) "
              f"{loads['viewer_s']:.2f} / {loads['viewer_min_s']:.2f} s wall, {loads['viewer_cpu_s']:.2f} / "
              f"{loads['viewer_cpu_min_s']:.2f} s viewer CPU" if "viewer_s" in loads else ""))
    print(f"peak memory (max RSS): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
