"""A camera from the traffic in a scene's masks (``s2p calibrate-camera --from-traffic``, after
``masks-from-video``): the tracks' mask centroids as points of motion, their
straight stretches, two orthogonal vanishing points, focal length and rotation, and the camera's
height from the pedestrians' and bicyclists' typical heights (geometry/vanishing.py). The
expected error is a bootstrap over the tracks (each resample of tracks solved again; the spread
of the focal length and the height). The camera's world frame is its own (origin below it, x
along the first road, z up): alone it places road users relative to the camera; with a few
clicked pairs its focal length is the solver's prior.

Units: pixels, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry import vanishing as V
from seg2pose.geometry.camera import Camera
from seg2pose.io.scene import Scene
from seg2pose.structures.masks import rle_stats

HEIGHT_CLASSES = ("pedestrian", "bicyclist")  # upright road users: head straight above the feet
BORDER = 2  # pixels: boxes this close to the image border are cut off
SIZE_SPREAD = 0.05  # share: the mean height of a site's pedestrians and bicyclists against the typical


@dataclass(frozen=True)
class TrafficOptions:
    """every: use every n-th frame; max_frames: at most this many frames read; bootstrap:
    resamples for the expected error; seed: the RANSAC's and bootstrap's random stream."""

    every: int = 1
    max_frames: int = 4000
    bootstrap: int = 30
    seed: int = 0


@dataclass
class TrafficCalibration:
    camera: Camera
    focal_sd: float
    height_m: float
    height_sd: float
    segments: int
    people: int
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        c = self.camera
        return (f"camera {c.name} from the traffic: focal {c.K[0, 0]:.1f} px (expected error "
                f"{self.focal_sd:.1f} px, {100 * self.focal_sd / c.K[0, 0]:.1f} %), height "
                f"{self.height_m:.2f} m (expected error {self.height_sd:.2f} m), from {self.segments} "
                f"straight stretches of motion and {self.people} upright road users; its world frame "
                "is its own (origin below the camera, x along the first road)")


def track_points(scene: Scene, camera: str, opts: TrafficOptions):
    """(tracks: list of (n, 2) mask centroids in time order, feet (N, 2) and heads (N, 2) (the
    boxes' bottom and top centres), their classes' typical heights (N,) and footprint depths
    (N,), metres). Centroids, not the
    boxes' bottom centres: a box's bottom centre slides over the road user's outline as the
    view turns, and its lines miss the vanishing point (on bench seed 100, camera c1: focal
    889 px from centroids, 818 px from bottom centres, truth 900)."""
    cam = scene.cameras[camera]
    names = scene.class_names_by_id()
    sizes = scene.class_sizes()
    by_track: dict[int, list] = {}
    feet, heads, hts, depths = [], [], [], []
    n = 0
    for frame, t in scene.iter_masks(camera):
        if frame % opts.every:
            continue
        n += 1
        if n > opts.max_frames:
            break
        _, cen, box = rle_stats(t.rles, t.height, t.width)
        inside = ((box[:, 0] > BORDER) & (box[:, 1] > BORDER) & (box[:, 2] < cam.width - BORDER)
                  & (box[:, 3] < cam.height - BORDER))
        for k in np.flatnonzero(inside):
            x0, y0, x1, y1 = box[k]
            by_track.setdefault(int(t.track_id[k]), []).append((frame, cen[k, 0], cen[k, 1]))
            name = names.get(int(t.class_id[k]))
            if name in HEIGHT_CLASSES:
                feet.append((0.5 * (x0 + x1), y1))
                heads.append((0.5 * (x0 + x1), y0))
                hts.append(sizes[name][2])
                # half the footprint's mean side: a standing person's near edge to its middle
                depths.append(0.25 * (sizes[name][0] + sizes[name][1]))
    tracks = []
    for rows in by_track.values():
        a = np.array(rows)
        cut = np.flatnonzero(np.diff(a[:, 0]) > 3 * opts.every) + 1  # gaps split a track
        tracks += [p[:, 1:] for p in np.split(a, cut) if len(p) >= 4]
    return (tracks, np.array(feet).reshape(-1, 2), np.array(heads).reshape(-1, 2), np.array(hts),
            np.array(depths))


def solve_traffic(tracks, feet, heads, hts, depths, width: int, height: int, rng
                  ) -> tuple[float, np.ndarray, float, int]:
    """(f, R, camera height, segments) from one set of tracks and upright road users (depths
    (N,) metres: from the lowest foot pixel to below the head, half the footprint)."""
    seg = V.track_segments(tracks)
    v1, v2, f = V.orthogonal_vps(seg, width, height, rng)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    R = V.rotation_from_vps(v1, v2, K)
    H = np.nan
    for _ in range(3):  # the footprint's depth in units of the camera's height needs the height
        off = 0.0 if not np.isfinite(H) else depths / H
        ratio = V.height_ratios(K, R, feet, heads, off)
        ok = np.isfinite(ratio) & (ratio > 0.01)
        if ok.sum() < 5:
            raise InputError(f"{int(ok.sum())} upright road users (pedestrians, bicyclists) measured: "
                             "too few for the camera's height")
        H = float(np.median(hts[ok] / ratio[ok]))
    return f, R, H, len(seg.lines)


def traffic_calibration(scene: Scene, camera: str, opts: TrafficOptions = TrafficOptions()
                        ) -> TrafficCalibration:
    """See the module doc."""
    cam0 = scene.cameras[camera]
    w, h = cam0.width, cam0.height
    tracks, feet, heads, hts, depths = track_points(scene, camera, opts)
    if len(tracks) < 4:
        raise InputError(f"camera {camera}: {len(tracks)} tracks in its masks; run masks-from-video "
                         "on a longer stretch of video first")
    rng = np.random.default_rng(opts.seed)
    f, R, H, nseg = solve_traffic(tracks, feet, heads, hts, depths, w, h, rng)
    fs, Hs = [], []
    for _ in range(opts.bootstrap):
        ti = rng.integers(len(tracks), size=len(tracks))
        pi = rng.integers(len(feet), size=len(feet))
        try:
            fb, _, Hb, _ = solve_traffic([tracks[i] for i in ti], feet[pi], heads[pi], hts[pi], depths[pi],
                                         w, h, rng)
        except InputError:
            continue
        fs.append(fb)
        Hs.append(Hb)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    C = np.array([0.0, 0.0, H])
    cam = Camera(camera, K, R, -R @ C, w, h)
    notes = [] if len(fs) >= opts.bootstrap // 2 else [f"only {len(fs)} of {opts.bootstrap} resamples solved"]
    # the height's error also holds how far this site's road users may be from the classes'
    # typical heights (SIZE_SPREAD of the height), which no resample of the same road users shows
    H_sd = float(np.hypot(_spread(Hs), SIZE_SPREAD * H))
    return TrafficCalibration(cam, _spread(fs), H, H_sd, nseg, len(feet), notes)


def _spread(a: list[float]) -> float:
    """A robust standard deviation (1.4826 x the median absolute deviation): a few resamples
    that lost one road's tracks must not make the stated error."""
    if len(a) < 2:
        return float("nan")
    x = np.asarray(a)
    return float(1.4826 * np.median(np.abs(x - np.median(x))))
