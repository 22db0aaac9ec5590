"""The synthetic four-arm junction: true ground surface, road layout and ground-point sampling.

World frame: metres, right-handed, z up, origin at the junction centre. The arms run along
+x (east), +y (north), -x (west), -y (south). Each arm has two lanes per direction
(``LANE`` m wide) so the carriageway spans |b| < ``ROAD_HALF`` across the arm; everything
outside the carriageway is raised sidewalk (``CURB`` m high) with rounded corners. A gentle
slope rises along the east arm, so the surface is not flat.

The renderer and the ground truth use the *true* surface ``true_height``; the method only sees
the sampled ground points (eq. (1) over them), as in the paper (184 points, denser along the
curb edges, section 4.1).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

LANE = 3.5            # m, lane width
ROAD_HALF = 2 * LANE  # m, half-width of the carriageway (two lanes per direction)
CURB = 0.15           # m, sidewalk height above the road
CURB_RAMP = 0.04      # m, horizontal width of the curb's face (a steep ramp, not a cliff)
SIDEWALK = 3.5        # m, sidewalk width (the walking line is in its middle)
CORNER_R = 3.0        # m, curb radius at the corners
CROSSWALK = (1.0, 4.0)  # m, crosswalk span along the arm, measured from the carriageway edge
STAGE = 80.0          # m, routes start and end this far from the centre along an arm (out of view)
SLOPE = 0.04          # rise per metre along the east arm, beyond SLOPE_START
SLOPE_START = 12.0    # m

ARM_ANGLES = {"E": 0.0, "N": np.pi / 2, "W": np.pi, "S": -np.pi / 2}


def curb_distance(xy: np.ndarray) -> np.ndarray:
    """Signed distance (N,) metres from the carriageway edge: > 0 on the sidewalk, < 0 on the
    road (exact near the edge, which is all the curb ramp needs). xy: (N, 2) metres."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    u = np.abs(xy[:, 0]) - ROAD_HALF
    v = np.abs(xy[:, 1]) - ROAD_HALF
    r = CORNER_R
    fillet = (u < r) & (v < r)
    # in the corner zone the sidewalk is the disc of radius r around (r, r): a rounded corner
    d_fillet = r - np.hypot(u - r, v - r)
    return np.where(fillet, d_fillet, np.minimum(u, v))


def base_height(xy: np.ndarray) -> np.ndarray:
    """The road's height (N,) metres without curbs: a smooth 4 % rise along the east arm."""
    x = np.asarray(xy, dtype=np.float64).reshape(-1, 2)[:, 0]
    return SLOPE * np.logaddexp(0.0, x - SLOPE_START)


def true_height(xy: np.ndarray) -> np.ndarray:
    """The true ground height z (N,) metres at top-down positions xy (N, 2) metres."""
    d = curb_distance(xy)
    curb = CURB * np.clip(d / CURB_RAMP + 0.5, 0.0, 1.0)
    return base_height(xy) + curb


def to_world(arm: str, a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """Arm coordinates -> world xy (N, 2): ``a`` metres outwards along the arm from the centre,
    ``b`` metres to the left when looking outwards."""
    th = ARM_ANGLES[arm]
    c, s = np.cos(th), np.sin(th)
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    return np.stack([a * c - b * s, a * s + b * c], axis=-1)


def ray_ground_points(origin: np.ndarray, dirs: np.ndarray, iterations: int = 6) -> np.ndarray:
    """Where rays (M, 3) from ``origin`` (3,) meet the true surface, by fixed-point iteration on
    the height (good enough for rendering the background; the surface slopes gently).
    Returns (M, 3) metres, NaN for rays that do not point down."""
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(dirs), 3), np.nan)
    down = dirs[:, 2] < -1e-6
    d = dirs[down]
    z = np.zeros(len(d))
    for _ in range(iterations):
        s = (z - origin[2]) / d[:, 2]
        p = origin[:2] + s[:, None] * d[:, :2]
        z = true_height(p)
    s = (z - origin[2]) / d[:, 2]
    out[down] = origin + s[:, None] * d
    return out


def sample_ground_points(rng: np.random.Generator, visible: Callable[[np.ndarray], np.ndarray], n: int = 184,
                         curb_share: float = 0.6, extent: float = 75.0) -> np.ndarray:
    """The paper's ground survey: ``n`` points (n, 3) metres on the true surface, around the
    area the cameras see, with ``curb_share`` of them in pairs straddling the curb edges
    (0.3 m either side), where the height changes most.

    visible: function (M, 2) xy -> (M,) bool, the area seen by at least one camera.
    """
    n_curb = int(round(n * curb_share)) // 2 * 2
    n_free = n - n_curb
    # candidate curb-edge locations: points on the edge found by walking from a random
    # sidewalk point along the gradient of the signed distance (computed numerically)
    pts: list[np.ndarray] = []
    cand = rng.uniform(-extent, extent, size=(20000, 2))
    d = curb_distance(cand)
    near = cand[(np.abs(d) < 2.5) & visible(cand)]
    eps = 1e-4
    gx = (curb_distance(near + [eps, 0]) - curb_distance(near - [eps, 0])) / (2 * eps)
    gy = (curb_distance(near + [0, eps]) - curb_distance(near - [0, eps])) / (2 * eps)
    g = np.stack([gx, gy], 1)
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
    edge = near - curb_distance(near)[:, None] * g  # one Newton step onto the edge (exact for lines)
    # spread the pairs along the edges: greedy thinning to at least 1.5 m apart
    order = rng.permutation(len(edge))
    chosen: list[int] = []
    for i in order:
        if len(chosen) >= n_curb // 2:
            break
        if not chosen or np.min(np.linalg.norm(edge[chosen] - edge[i], axis=1)) > 1.5:
            chosen.append(i)
    e, gg = edge[chosen], g[chosen]
    pair = np.concatenate([e + 0.3 * gg, e - 0.3 * gg])
    pts.append(pair)
    # the rest spread over the visible area, at least 2 m apart
    free = rng.uniform(-extent, extent, size=(40000, 2))
    free = free[visible(free)]
    keep: list[np.ndarray] = []
    for p in free:
        if len(keep) >= n_free + (n_curb - len(pair)):
            break
        if not keep or np.min(np.linalg.norm(np.asarray(keep) - p, axis=1)) > 2.0:
            if len(pair) == 0 or np.min(np.linalg.norm(pair - p, axis=1)) > 1.0:
                keep.append(p)
    pts.append(np.asarray(keep).reshape(-1, 2))
    xy = np.concatenate(pts)[:n]
    return np.column_stack([xy, true_height(xy)])
