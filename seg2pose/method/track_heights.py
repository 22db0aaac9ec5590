"""Per-track heights fitted at inference time, without annotation (``s2p run --track-heights``).

A normal position (paper 3.2) assumes the class's default height h0 for the 3D point behind the
mask centre. A road user bigger or smaller than its class's default is placed too far or too
near along the camera's line of sight, by about ``dh * d`` where ``d = dp/dh`` (metres per
metre, pointing towards the camera's foot, length ~ ground distance / camera height). Its
height is constant along its track, so one offset ``dh`` per track is fitted to what the track
itself says, linearised around h0:

    p_v(dh) = p_v + dh * d_v          p_v: a view's estimate (normal position + residual), (2,)

and minimising, per track k, with Huber weights (IRLS, ``huber`` metres) on each 2D residual
(cross-camera rows only where the views' directions differ by ``min_spread`` or more):

    cross * sum_{poses seen by >= 2 cameras} sum_views |(p_v - q_j) + dh (d_v - D_j)|^2
  + smooth * sum_{3 consecutive frames} |D2 q + dh D2 D|^2
  + prior * dh^2

(q_j, D_j: the mean of p_v, d_v over the views of pose j; D2: second difference along the
track; d is taken at the pose's fused place, see ``directions_at``). Each IRLS step is closed
form, dh = -B / (A + prior), done for all tracks at once with ``np.bincount``, bounded to
``bounds`` times the default; a second Gauss-Newton pass relinearises at the fitted heights.
The views are then put at their track's height exactly (``normal_positions`` on each view's own
ray at h0 + dh), not along the linearisation.

What each term can know (docs/RESULTS.md, "Track consistency"): on a flat (or plane) ground the
positions of one camera at height h are the positions at h0 scaled about the camera's foot by
(H - h) / (H - h0) (H: the camera's height), so a wrong height maps a track onto a similar
track -- straight stays straight, a constant speed stays constant. The smoothness term
carries no information on the height from one camera (on a curved ground a little);
worse, shrinking a noisy path towards the camera shrinks its second differences, so the term
pulls dh up whatever the truth (measured: it only harms; off by default). The cross-camera
term triangulates: the views' positions at the true height coincide, and a wrong height moves
them apart by dh times the difference of their directions, ~ (camera baseline) / H -- 0.02 for
lenses of one device 20 cm apart, ~2 for poles 36 m apart. The prior keeps the default where
the data carry nothing (one camera, short tracks).

For Seg2PoseNet runs the correction moves the network's estimate (normal position + residual)
along the same d: the network saw the crop and the normal position at h0, its residual is what
it learned to add at h0, and what stays after it (docs/RESULTS.md, "Error budget") is mostly a
radial offset constant per road user -- the shape a height offset makes. Re-running the network
from a corrected normal position would ask it for a residual at a height it was never trained
at. views.csv holds the normal positions at the fitted heights, so that views.csv and
poses.csv stay consistent (fusing views.csv again gives the same poses).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from seg2pose.geometry.normal import normal_positions
from seg2pose.io.run import ViewTable


@dataclass(frozen=True)
class TrackHeightSettings:
    """Weights of the per-track fit (see module docstring). prior: dimensionless (the objective's
    data terms are in m^2, dh in m, d in m/m: a track needs sum |a|^2 ~ prior of informative
    residual before its height moves halfway); huber: metres; bounds: the fitted height's range
    as multiples of the class's default height."""

    cross: float = 1.0
    smooth: float = 0.0
    prior: float = 1.0      # chosen on the tuning seeds (docs/RESULTS.md, "Track consistency")
    huber: float = 0.1
    # (class, prior) pairs overriding ``prior`` for that class's tracks: pedestrians' heights
    # vary least against the other errors of their positions (with prior 1 they got worse)
    class_prior: tuple = (("pedestrian", 10.0),)
    bounds: tuple[float, float] = (0.6, 1.4)
    iterations: int = 6
    min_frames: int = 5     # tracks with fewer poses keep the default
    relinearise: int = 2    # Gauss-Newton passes (each linearised at the last pass's heights)
    # cross-camera rows whose |d_v - D_j| (m/m) is below this are dropped. Off (0) by default:
    # lenses of one device (20-40 cm apart, |d_v - D_j| ~ 0.01-0.02) looked too close to
    # carry height information, but measured on the tuning seeds they do (their parallax
    # triangulates the mask centre's height, pooled over hundreds of frames); 0.1 drops them
    min_spread: float = 0.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["bounds"] = list(self.bounds)
        d["class_prior"] = dict(self.class_prior)
        return d


DEFAULT_SETTINGS = TrackHeightSettings()


def height_directions(scene, camera: np.ndarray, uv: np.ndarray, heights: np.ndarray,
                      eps: float = 0.05) -> np.ndarray:
    """d = dp/dh (N, 2), metres of ground position per metre of assumed height, of the rays
    through pixels ``uv`` (N, 2) of cameras ``camera`` (N,) names: central differences of the
    normal position (``normal_positions`` on the scene's ground) at heights +-eps around
    ``heights`` (N,) metres. NaN where a ray misses the ground."""
    d = np.full((len(uv), 2), np.nan)
    for cam in np.unique(camera):
        i = np.flatnonzero((camera == cam) & np.isfinite(heights) & np.isfinite(uv).all(1))
        if not len(i):
            continue
        c = scene.cameras[str(cam)]
        hi, _ = normal_positions(c, scene.ground, uv[i], heights[i] + eps)
        lo, _ = normal_positions(c, scene.ground, uv[i], heights[i] - eps)
        d[i] = (hi[:, :2] - lo[:, :2]) / (2 * eps)
    return d


def directions_at(scene, camera: np.ndarray, xy: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """dp/dh (N, 2) m/m of cameras ``camera`` (N,) at ground places ``xy`` (N, 2) metres (the
    ray through the point ``heights`` (N,) metres above the ground there).

    The fit takes each view's direction at its pose's fused place, not at the view's own
    estimate: dp/dh ~ (camera foot - place) / camera height, so a direction taken at a noisy
    estimate carries that estimate's noise, correlated with the residual it multiplies -- a
    bias that pulls every height up (towards the camera), and that made lenses 20 cm apart
    look informative."""
    X = np.column_stack([xy, scene.ground.height(xy) + heights])
    uv = np.full((len(xy), 2), np.nan)
    for cam in np.unique(camera):
        i = np.flatnonzero(camera == cam)
        p, _, front = scene.cameras[str(cam)].project_points(X[i])
        uv[i] = np.where(front[:, None], p, np.nan)
    return height_directions(scene, camera, uv, heights)


def _rows(track: np.ndarray, frame: np.ndarray, p: np.ndarray, d: np.ndarray, n_tracks: int,
          s: TrackHeightSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The linear residual rows r = b + dh[k] a of all tracks: k (R,) track index, b (R, 2) m,
    a (R, 2) m/m, w (R,) weights; and the number of poses (frames) of each track (n_tracks,)."""
    keys = np.stack([track, frame], axis=1)
    ukeys, pose = np.unique(keys, axis=0, return_inverse=True)
    pose = pose.reshape(-1)
    n_views = np.bincount(pose, minlength=len(ukeys)).astype(float)
    q = np.stack([np.bincount(pose, p[:, c], len(ukeys)) for c in range(2)], 1) / n_views[:, None]
    D = np.stack([np.bincount(pose, d[:, c], len(ukeys)) for c in range(2)], 1) / n_views[:, None]
    ks, bs, as_, ws = [], [], [], []
    if s.cross > 0:
        multi = n_views[pose] >= 2
        multi &= np.linalg.norm(d - D[pose], axis=1) >= s.min_spread
        ks.append(track[multi])
        bs.append(p[multi] - q[pose[multi]])
        as_.append(d[multi] - D[pose[multi]])
        ws.append(np.full(int(multi.sum()), s.cross))
    if s.smooth > 0 and len(ukeys) >= 3:
        # ukeys is sorted by track, then frame: a triple is three consecutive frames of one track
        t, f = ukeys[:, 0], ukeys[:, 1]
        mid = np.flatnonzero((t[1:-1] == t[:-2]) & (t[1:-1] == t[2:])
                             & (f[1:-1] - f[:-2] == 1) & (f[2:] - f[1:-1] == 1)) + 1
        ks.append(t[mid])
        bs.append(q[mid - 1] - 2 * q[mid] + q[mid + 1])
        as_.append(D[mid - 1] - 2 * D[mid] + D[mid + 1])
        # a second difference of white noise has 6x its variance: weigh it as one frame
        ws.append(np.full(len(mid), s.smooth / 6.0))
    n_frames = np.bincount(ukeys[:, 0], minlength=n_tracks)
    if not ks:
        z = np.zeros(0)
        return z.astype(np.int64), np.zeros((0, 2)), np.zeros((0, 2)), z, n_frames
    return (np.concatenate(ks), np.concatenate(bs), np.concatenate(as_), np.concatenate(ws),
            n_frames)


def fit_offsets(track: np.ndarray, frame: np.ndarray, p: np.ndarray, d: np.ndarray,
                h0: np.ndarray, n_tracks: int, s: TrackHeightSettings = DEFAULT_SETTINGS,
                start: np.ndarray | None = None, prior: np.ndarray | None = None) -> np.ndarray:
    """Height offsets dh (n_tracks,) metres, all tracks at once (see module docstring).

    track: (N,) track index in [0, n_tracks) of each view; frame: (N,) ints; p: (N, 2) the
    views' estimates at heights h0 + start, metres; d: (N, 2) dp/dh there, m/m; h0: (n_tracks,)
    default heights, metres (the prior pulls towards them, bounds are relative to them);
    start: (n_tracks,) the offsets p was computed at (None: zeros); prior: (n_tracks,) the
    prior weight of each track (None: ``s.prior`` for all). Rows with a non-finite p or d are
    ignored."""
    ok = np.isfinite(p).all(1) & np.isfinite(d).all(1)
    k, b, a, w0, n_frames = _rows(track[ok], frame[ok], p[ok], d[ok], n_tracks, s)
    start = np.zeros(n_tracks) if start is None else np.asarray(start, float)
    lam = np.full(n_tracks, s.prior) if prior is None else np.asarray(prior, float)
    lo = (s.bounds[0] - 1.0) * h0 - start
    hi = (s.bounds[1] - 1.0) * h0 - start
    step = np.zeros(n_tracks)  # the change of dh from start
    aa = np.einsum("rc,rc->r", a, a)
    ab = np.einsum("rc,rc->r", a, b)
    for _ in range(max(1, s.iterations)):
        r = np.linalg.norm(b + step[k, None] * a, axis=1)
        w = w0 * np.minimum(1.0, s.huber / np.maximum(r, 1e-12))  # Huber as IRLS weights
        A = np.bincount(k, w * aa, n_tracks)
        B = np.bincount(k, w * ab, n_tracks)
        # minimise sum w |b + step a|^2 + prior (start + step)^2
        step = np.clip(-(B + lam * start) / (A + lam), lo, hi)
    dh = start + step
    dh[n_frames < s.min_frames] = 0.0
    return dh


def fit_offsets_loop(track: np.ndarray, frame: np.ndarray, p: np.ndarray, d: np.ndarray,
                     h0: np.ndarray, n_tracks: int, s: TrackHeightSettings = DEFAULT_SETTINGS
                     ) -> np.ndarray:
    """``fit_offsets`` one track at a time (the reference the vectorised version is tested
    against)."""
    out = np.zeros(n_tracks)
    for t in range(n_tracks):
        i = track == t
        if i.any():
            out[t] = fit_offsets(np.zeros(int(i.sum()), np.int64), frame[i], p[i], d[i],
                                 h0[t:t + 1], 1, s)[0]
    return out


def apply_track_heights(scene, views: ViewTable, s: TrackHeightSettings = DEFAULT_SETTINGS
                        ) -> tuple[ViewTable, dict, str]:
    """Fit one height per tracked road user and put its views' normal positions at that height.

    Returns the corrected views (a copy; untracked views, id -1, and views without a class are
    unchanged), the run.json entry and the text of track_heights.csv
    (track_id,class,default_height,height,n_views)."""
    defaults = scene.default_heights()
    h = np.array([defaults.get(str(c), np.nan) for c in views.cls])
    est = views.normal[:, :2] + views.residual
    use = (views.track_id >= 0) & np.isfinite(h) & np.isfinite(est).all(1)
    tids, tix = np.unique(views.track_id[use], return_inverse=True)
    tix = tix.reshape(-1)
    first = np.zeros(len(tids), np.int64)
    first[tix[::-1]] = np.arange(len(tix))[::-1]  # first view of each track (its class, h0)
    idx = np.flatnonzero(use)
    _, pose = np.unique(np.stack([tix, views.frame[idx]], 1), axis=0, return_inverse=True)
    pose = pose.reshape(-1)
    n_pose = np.bincount(pose)[:, None]
    h0 = h[idx][first]
    cls = views.cls[idx][first]
    by_class = dict(s.class_prior)
    lam = np.array([by_class.get(str(c), s.prior) for c in cls], float)
    out = views.take(np.arange(len(views)))
    dh = np.zeros(len(tids))
    for _ in range(max(1, s.relinearise)):
        # linearised at the current heights (Gauss-Newton): the views' estimates there and the
        # directions at their poses' fused places
        p = out.normal[idx, :2] + views.residual[idx]
        q = np.stack([np.bincount(pose, p[:, c]) for c in range(2)], 1) / n_pose
        d = directions_at(scene, views.camera[idx], q[pose], h[idx] + dh[tix])
        new = fit_offsets(tix, views.frame[idx], p, d, h0, len(tids), s, start=dh, prior=lam)
        # the fit is linear; the correction is exact: each view's normal position at its
        # track's height, on its own ray (the residual of a Seg2PoseNet run is kept as it is)
        move = np.flatnonzero(new[tix] != dh[tix])
        dh = new
        for cam in np.unique(views.camera[idx[move]]):
            j = move[views.camera[idx[move]] == cam]
            X, _ = normal_positions(scene.cameras[str(cam)], scene.ground, views.uv[idx[j]],
                                    h[idx[j]] + dh[tix[j]])
            ok = np.isfinite(X[:, 0])
            out.normal[idx[j[ok]]] = X[ok]
        if not len(move):
            break
    n_views = np.bincount(tix, minlength=len(tids))
    lines = ["track_id,class,default_height,height,n_views"]
    lines += [f"{t},{c},{a:.4f},{a + b:.4f},{n}" for t, c, a, b, n in zip(tids, cls, h0, dh, n_views)]
    moved = np.abs(dh) >= 0.01
    meta = {**s.to_dict(), "file": "track_heights.csv", "n_tracks": int(len(tids)),
            "n_moved_1cm": int(moved.sum()),
            "median_abs_offset_m": float(np.median(np.abs(dh))) if len(dh) else 0.0,
            "max_abs_offset_m": float(np.abs(dh).max(initial=0.0))}
    return out, meta, "\n".join(lines) + "\n"
