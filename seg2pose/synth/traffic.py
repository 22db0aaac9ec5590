"""Road-user motion: routes through the junction, speed profiles, traffic lights and queues.

Each class has a population of road users (the paper's 43 pedestrians, 12 bicyclists and 28
cars at paper scale). A population member alternates between a *visit* (a route through the
modelled area, from one arm's far end to another's) and a pause "elsewhere in town". Every
visit is a new track (a new ``track_id``), as a tracker would see a road user that re-enters.

- Cars keep to lanes (two per direction, right-hand traffic), turn right from the outer lane
  and left from the inner one, slow down in turns, stop at red lights (a two-phase signal),
  queue behind each other, and never run into the car ahead in their entry lane.
- Bicyclists ride along the road edge with the same rules.
- Pedestrians walk along the sidewalks and across the crosswalks (waiting at the curb before
  crossing); some stop for a while, some stand still for most of their visit.

Everything is a function of time; positions are sampled at the frame times. Units: metres,
seconds, radians (heading counter-clockwise from +x).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from seg2pose.synth import junction as J

GREEN, ALL_RED = 18.0, 3.0  # s, signal timing; N-S green first, then E-W
CYCLE = 2 * (GREEN + ALL_RED)
TURN_A = J.ROAD_HALF + J.CORNER_R  # m from the centre where turns start and end
STOP_A = J.ROAD_HALF + J.CROSSWALK[1] + 1.0  # m, the stop line
DS = 0.25  # m, grid step of speed profiles


def green_start(arm: str, t: float) -> float:
    """The first time >= t at which the signal for ``arm`` is green (s)."""
    off = 0.0 if arm in ("N", "S") else GREEN + ALL_RED
    k = np.floor((t - off) / CYCLE)
    start = off + k * CYCLE
    if t < start + GREEN:
        return max(t, start)
    return start + CYCLE


@dataclass
class Route:
    """A polyline path: xy (K, 2) metres, cumulative length s (K,), and per-vertex speed limit."""

    xy: np.ndarray
    s: np.ndarray
    vmax: np.ndarray
    stop_s: float | None = None  # arc length of the stop line, when the route has one
    shared_s: float = 0.0         # arc length until which the route shares its entry lane


def _polyline(xy: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def _bezier(p0, c, p2, n=24) -> np.ndarray:
    u = np.linspace(0, 1, n)[:, None]
    return (1 - u) ** 2 * p0 + 2 * u * (1 - u) * c + u ** 2 * p2


def _line_intersection(p, d, q, e) -> np.ndarray:
    A = np.column_stack([d, -e])
    if abs(np.linalg.det(A)) < 1e-9:
        return 0.5 * (p + q)
    s = np.linalg.solve(A, q - p)[0]
    return p + s * d


ARMS = ["E", "N", "W", "S"]


def vehicle_route(rng: np.random.Generator, bike: bool) -> tuple[Route, str]:
    """A route for a car or bicyclist: entry arm, movement (straight/right/left), lanes."""
    ai = int(rng.integers(4))
    arm = ARMS[ai]
    mv = rng.choice(["straight", "right", "left"], p=[0.6, 0.2, 0.2])
    exit_arm = ARMS[{"straight": ai + 2, "right": ai + 1, "left": ai + 3}[mv] % 4]
    if bike:
        b_in = J.ROAD_HALF - 0.5
        b_out = -b_in
        v_turn = 3.5 if mv == "right" else 4.5
    else:
        lane = {"right": 1, "left": 0}.get(mv, int(rng.integers(2)))
        b_in = J.LANE * (0.5 + lane)
        b_out = -b_in
        v_turn = 4.5 if mv == "right" else 6.5
    a_in = np.linspace(J.STAGE, TURN_A, 12)
    p_in = J.to_world(arm, a_in, b_in)
    a_out = np.linspace(TURN_A, J.STAGE, 12)
    p_out = J.to_world(exit_arm, a_out, b_out)
    if mv == "straight":
        mid = np.linspace(p_in[-1], p_out[0], 12)
    else:
        d_in = p_in[-1] - p_in[-2]
        d_out = p_out[1] - p_out[0]
        c = _line_intersection(p_in[-1], d_in, p_out[0], d_out)
        mid = _bezier(p_in[-1], c, p_out[0])
    xy = np.concatenate([p_in, mid[1:-1], p_out])
    s = _polyline(xy)
    vmax = np.full(len(xy), np.inf)
    if mv != "straight":
        vmax[len(p_in) - 1:len(p_in) + len(mid) - 1] = v_turn
    stop_s = J.STAGE - STOP_A
    return Route(xy, s, vmax, stop_s=stop_s, shared_s=J.STAGE - TURN_A), arm


# --- pedestrians: a graph of sidewalk lines and crosswalks -------------------------------------
_C = J.ROAD_HALF + J.SIDEWALK / 2      # walking line's distance from the arm axis
_X = J.ROAD_HALF + sum(J.CROSSWALK) / 2  # crosswalk centre along the arm


def _ped_nodes() -> tuple[dict, dict]:
    nodes, edges = {}, {}
    for sx in (-1, 1):
        for sy in (-1, 1):
            q = (sx, sy)
            nodes[q + ("xend",)] = (sx * J.STAGE, sy * _C)
            nodes[q + ("xcross",)] = (sx * _X, sy * _C)
            nodes[q + ("corner",)] = (sx * _C, sy * _C)
            nodes[q + ("ycross",)] = (sx * _C, sy * _X)
            nodes[q + ("yend",)] = (sx * _C, sy * J.STAGE)
            chain = ["xend", "xcross", "corner", "ycross", "yend"]
            for a, b in zip(chain[:-1], chain[1:]):
                edges.setdefault(q + (a,), []).append(q + (b,))
                edges.setdefault(q + (b,), []).append(q + (a,))
    for sx in (-1, 1):  # crosswalks across the east/west arms connect sy = -1 and +1
        a, b = (sx, -1, "xcross"), (sx, 1, "xcross")
        edges[a].append(b)
        edges[b].append(a)
    for sy in (-1, 1):
        a, b = (-1, sy, "ycross"), (1, sy, "ycross")
        edges[a].append(b)
        edges[b].append(a)
    return nodes, edges


PED_NODES, PED_EDGES = _ped_nodes()
PED_ENDS = [k for k in PED_NODES if k[2] in ("xend", "yend")]


def pedestrian_route(rng: np.random.Generator) -> tuple[np.ndarray, list[int]]:
    """A walk from one sidewalk end to another: waypoints (K, 2) metres and the indices of
    waypoints where a crossing starts (the pedestrian waits there at the curb)."""
    node = PED_ENDS[int(rng.integers(len(PED_ENDS)))]
    path, prev = [node], None
    crossings = 0
    for _ in range(40):
        nxt = [n for n in PED_EDGES[node] if n != prev]
        cross = [n for n in nxt if n[:2] != node[:2]]
        if crossings >= 2:
            nxt = [n for n in nxt if n not in cross] or nxt
        n = nxt[int(rng.integers(len(nxt)))]
        prev, node = node, n
        path.append(n)
        if n[:2] != prev[:2]:
            crossings += 1
        if n[2] in ("xend", "yend"):
            break
    xy = np.array([PED_NODES[n] for n in path], float)
    waits = [i for i in range(len(path) - 1) if path[i][:2] != path[i + 1][:2]]
    return xy, waits


def _offset(xy: np.ndarray, off: float) -> np.ndarray:
    """Shift a polyline sideways by ``off`` metres (to the left of the walking direction)."""
    t = np.gradient(xy, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    return xy + off * np.stack([-t[:, 1], t[:, 0]], 1)


# --- speed profiles -------------------------------------------------------------------------------
def _profile(route: Route, v_cruise: float, acc: float, dec: float,
             stop_at: float | None, v0: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Time t(s) along the route on a grid: (s_grid (G,), t_grid (G,)) with t_grid[0] = 0.

    The speed is the largest one under the cruise speed and the route's limits that respects
    acceleration ``acc`` and deceleration ``dec`` (m/s^2) and is 0 at ``stop_at``: the forward
    and backward passes of the usual kinematic bound, vectorised as cumulative minima."""
    s = np.arange(0.0, route.s[-1] + DS, DS)
    s[-1] = min(s[-1], route.s[-1])
    lim = np.minimum(v_cruise, np.interp(s, route.s, np.where(np.isfinite(route.vmax), route.vmax, 1e6)))
    v2 = lim ** 2
    if stop_at is not None:
        k = int(np.clip(round(stop_at / DS), 0, len(s) - 1))
        v2[k] = 0.0
    if v0 is not None:
        v2[0] = min(v2[0], v0 ** 2)
    # forward: v^2(s_i) <= v^2(s_j) + 2 acc (s_i - s_j) for j <= i
    v2 = np.minimum(v2, 2 * acc * s + np.minimum.accumulate(v2 - 2 * acc * s))
    # backward: v^2(s_i) <= v^2(s_j) + 2 dec (s_j - s_i) for j >= i
    r = v2[::-1]
    sr = s[::-1]
    v2 = np.minimum(r, -2 * dec * sr + np.minimum.accumulate(r + 2 * dec * sr))[::-1]
    v = np.sqrt(np.maximum(v2, 0))
    vm = np.maximum(0.5 * (v[1:] + v[:-1]), 0.05)
    t = np.concatenate([[0.0], np.cumsum(np.diff(s) / vm)])
    return s, t


@dataclass
class Visit:
    """One road user's pass through the scene: sampled at its frames."""

    cls: str
    frames: np.ndarray   # (n,) int
    xy: np.ndarray       # (n, 2) metres
    heading: np.ndarray  # (n,) radians
    phase: np.ndarray    # (n,) gait phase, radians
    t0: float            # s, start time


def _sample(s_of_t_s: np.ndarray, s_of_t_t: np.ndarray, xy: np.ndarray, s_nodes: np.ndarray,
            t0: float, dt: float, stride: float) -> tuple[np.ndarray, ...]:
    """Positions at frame times within [t0, t0 + duration]."""
    f0 = int(np.ceil(t0 / dt - 1e-9))
    f1 = int(np.floor((t0 + s_of_t_t[-1]) / dt + 1e-9))
    frames = np.arange(f0, f1 + 1)
    tt = frames * dt - t0
    s = np.interp(tt, s_of_t_t, s_of_t_s)
    p = np.column_stack([np.interp(s, s_nodes, xy[:, 0]), np.interp(s, s_nodes, xy[:, 1])])
    seg = np.diff(xy, axis=0)
    ang = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    # heading: the segment direction, blended over 1 m around the vertices (no snapping)
    mids = 0.5 * (s_nodes[1:] + s_nodes[:-1])
    hd = np.interp(s, mids, ang) if len(mids) > 1 else np.full(len(s), ang[0])
    hd = (hd + np.pi) % (2 * np.pi) - np.pi
    return frames, p, hd, 2 * np.pi * s / stride


@dataclass
class TrafficConfig:
    """Knobs of the traffic model (recorded in scene.json extra.generator.traffic)."""

    population: dict  # class -> number of road users (paper: 43 / 12 / 28)
    mean_pause_s: dict  # class -> mean pause between visits, seconds
    warmup_s: float = 60.0  # simulate this long before frame 0 so the scene starts busy

    def to_dict(self) -> dict:
        return {"population": dict(self.population), "mean_pause_s": dict(self.mean_pause_s),
                "warmup_s": self.warmup_s}


def simulate(cfg: TrafficConfig, n_frames: int, dt: float, seed: int) -> list[Visit]:
    """All visits that overlap frames [0, n_frames), in order of start time (deterministic)."""
    rng = np.random.default_rng([seed, 11])
    t_end = n_frames * dt
    heap: list[tuple[float, int, str]] = []
    k = 0
    for cls in ("car", "bicyclist", "pedestrian"):
        for _ in range(int(cfg.population.get(cls, 0))):
            t = -cfg.warmup_s + rng.uniform(0, cfg.mean_pause_s.get(cls, 30.0) + cfg.warmup_s)
            heap.append((t, k, cls))
            k += 1
    heapq.heapify(heap)
    lane_last: dict[tuple, tuple] = {}   # lane -> (s_grid, t_grid, t0, length, shared_s)
    queue: dict[tuple, tuple[float, int]] = {}  # lane -> (green time the queue waits for, count)
    visits: list[Visit] = []
    while heap:
        t0, slot, cls = heapq.heappop(heap)
        if t0 >= t_end:
            continue
        if cls == "pedestrian":
            v = _pedestrian_visit(rng, t0, dt)
        else:
            v = _vehicle_visit(rng, cls, t0, dt, lane_last, queue)
        dur = (v.frames[-1] * dt - v.t0) if len(v.frames) else 0.0
        if len(v.frames) and v.frames[-1] >= 0:
            keep = (v.frames >= 0) & (v.frames < n_frames)
            if keep.any():
                visits.append(Visit(cls, v.frames[keep], v.xy[keep], v.heading[keep],
                                    v.phase[keep], v.t0))
        t_next = v.t0 + max(dur, 1.0) + rng.exponential(cfg.mean_pause_s.get(cls, 30.0))
        heapq.heappush(heap, (t_next, slot, cls))
    visits.sort(key=lambda v: (v.frames[0], v.t0))
    return visits


def _vehicle_visit(rng, cls, t0, dt, lane_last, queue) -> Visit:
    bike = cls == "bicyclist"
    route, arm = vehicle_route(rng, bike)
    lane = (arm, bike, round(float(route.xy[0, 0]), 2), round(float(route.xy[0, 1]), 2))
    v_cruise = rng.uniform(4.0, 6.5) if bike else rng.uniform(8.0, 12.5)
    acc, dec = (1.0, 1.5) if bike else (2.0, 3.0)
    length = 1.8 if bike else 4.8
    gap = (length + 2.0)
    # free run: does it reach the stop line on red?
    s_g, t_g = _profile(route, v_cruise, acc, dec, None)
    t_arr = t0 + np.interp(route.stop_s, s_g, t_g)
    g = green_start(arm, t_arr)
    if g > t_arr + 1e-6:
        # red: stop behind the cars already queued for this green
        qg, qn = queue.get(lane, (None, 0))
        n_ahead = qn if qg == g else 0
        queue[lane] = (g, n_ahead + 1)
        stop = route.stop_s - n_ahead * gap
        s_g, t_g = _profile(route, v_cruise, acc, dec, max(stop, 1.0))
        t_stop = np.interp(stop, s_g, t_g)
        dwell = max(0.0, g + 0.8 + 1.2 * n_ahead - (t0 + t_stop))
        t_g = t_g + np.where(s_g > stop + 1e-9, dwell, 0.0)
    # never closer than ``gap`` to the previous vehicle of this lane while sharing it: start later
    prev = lane_last.get(lane)
    if prev is not None:
        ps, pt, pt0, _, pshared = prev
        for _ in range(60):
            tt = np.linspace(t0, t0 + t_g[-1], 200)
            s_me = np.interp(tt - t0, t_g, s_g)
            s_prev = np.interp(tt - pt0, pt, ps, left=-1e9, right=1e9)
            shared = (s_me < pshared)
            if not np.any(shared & (s_prev - s_me < gap)):
                break
            t0 += 0.5
    lane_last[lane] = (s_g, t_g, t0, length, route.shared_s)
    frames, p, hd, ph = _sample(s_g, t_g, route.xy, route.s, t0, dt, stride=1e9)
    return Visit(cls, frames, p, hd, ph, t0)


def _densify(xy: np.ndarray, step: float) -> np.ndarray:
    """Resample a polyline (K, 2) with vertices at most ``step`` metres apart (keeps corners)."""
    out = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)


def _pedestrian_visit(rng, t0, dt) -> Visit:
    nodes, waits = pedestrian_route(rng)
    s_wait = _polyline(nodes)[waits] if waits else np.zeros(0)
    xy = _offset(_densify(nodes, 0.5), rng.uniform(-1.1, 1.1))
    s_nodes = _polyline(xy)
    s_wait = s_wait * (s_nodes[-1] / max(_polyline(nodes)[-1], 1e-9))  # offset changes lengths
    speed = rng.uniform(1.05, 1.6)
    s = s_nodes.copy()
    t = s / speed
    # waits: at the curb before each crossing; sometimes a pause anywhere; some standers
    stops = [(sw, rng.uniform(0.0, 8.0)) for sw in s_wait]
    u = rng.random()
    if u < 0.12:      # a stander: stays for most of the visit
        stops.append((rng.uniform(0, s_nodes[-1]), rng.uniform(40.0, 150.0)))
    elif u < 0.35:    # a pause: chatting, looking at a phone
        stops.append((rng.uniform(0, s_nodes[-1]), rng.uniform(5.0, 30.0)))
    for s_stop, dwell in stops:
        if dwell < 1e-3:
            continue
        t_a = np.interp(s_stop, s, t)
        k = int(np.searchsorted(s, s_stop, side="right"))
        t = np.where(s > s_stop, t + dwell, t)
        s = np.insert(s, k, [s_stop, s_stop])
        t = np.insert(t, k, [t_a, t_a + dwell])
    t = t + np.arange(len(t)) * 1e-9  # strictly increasing for interpolation
    frames, p, hd, ph = _sample(s, t, xy, s_nodes, t0, dt, stride=rng.uniform(1.2, 1.5))
    return Visit("pedestrian", frames, p, hd, ph, t0)
