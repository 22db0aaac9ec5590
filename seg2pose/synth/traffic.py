"""Road-user motion: speed profiles, traffic lights and queues along the routes of
``seg2pose.synth.routes``.

Each class has a population of road users (the paper's 43 pedestrians, 12 bicyclists and 28
cars at paper scale). A population member alternates between a *visit* (a route through the
modelled area, from one arm's far end to another's) and a pause "elsewhere in town", like
CARLA's road users wandering around the map; it keeps its identity (and shape) on every visit.

- Cars keep to lanes (two per direction, right-hand traffic), turn right from the outer lane
  and left from the inner one, slow down in turns, stop at red lights (a two-phase signal),
  queue behind each other, and never run into the car ahead in their entry lane.
- Bicyclists ride along the road edge with the same rules.
- Pedestrians walk along the sidewalks and across the crosswalks (waiting at the curb before
  crossing); some stop for a while, some stand still for most of their visit. With
  ``group_share`` > 0 some walk in groups of two or three (friends, a parent and a child): the
  same members every visit, side by side 0.7 m apart, a little ahead of or behind each other,
  stopping and crossing together; traffic yields to the group as one wide walker.

Everything is a function of time; positions are sampled at the frame times. Units: metres,
seconds, radians (heading counter-clockwise from +x).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from seg2pose.synth import junction as J
from seg2pose.synth.routes import (
    Route,
    arc_lengths,
    densify,
    green_start,
    offset_polyline,
    pedestrian_route,
    vehicle_route,
)

DS = 0.25  # m, grid step of speed profiles


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
    """One pass of a road user through the scene, sampled at its frames."""

    cls: str
    frames: np.ndarray   # (n,) int
    xy: np.ndarray       # (n, 2) metres
    heading: np.ndarray  # (n,) radians
    phase: np.ndarray    # (n,) gait phase, radians
    t0: float            # s, start time
    member: int = -1     # the population member (road user) making this visit


def _pose_at(s: np.ndarray, xy: np.ndarray, s_nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 2) and headings (n,) at arc lengths s (n,) along a polyline."""
    p = np.column_stack([np.interp(s, s_nodes, xy[:, 0]), np.interp(s, s_nodes, xy[:, 1])])
    seg = np.diff(xy, axis=0)
    ang = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    # heading: the segment direction, interpolated between segment midpoints (no snapping)
    mids = 0.5 * (s_nodes[1:] + s_nodes[:-1])
    hd = np.interp(s, mids, ang) if len(mids) > 1 else np.full(len(s), ang[0])
    return p, (hd + np.pi) % (2 * np.pi) - np.pi


def _hold(s_g: np.ndarray, t_g: np.ndarray, s_hold: float, dwell: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """Insert a stationary period of ``dwell`` seconds at arc length ``s_hold`` into t(s)."""
    if dwell <= 1e-6:
        return s_g, t_g
    t_a = float(np.interp(s_hold, s_g, t_g))
    k = int(np.searchsorted(s_g, s_hold, side="right"))
    t = np.where(s_g > s_hold, t_g + dwell, t_g)
    return np.insert(s_g, k, [s_hold, s_hold]), np.insert(t, k, [t_a, t_a + dwell])


@dataclass
class Traj:
    """A scheduled road user: start time, t(s) table, path, footprint half sizes (metres)."""

    t0: float
    s_g: np.ndarray
    t_g: np.ndarray
    xy: np.ndarray
    s_nodes: np.ndarray
    half: tuple[float, float]  # half length, half width
    vehicle: bool
    gave_up: bool = False      # still in conflict after MAX_YIELD_STEPS

    @property
    def t1(self) -> float:
        return self.t0 + float(self.t_g[-1])

    def at(self, tt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arc length, position and heading at absolute times tt; NaN outside the visit."""
        s = np.interp(tt - self.t0, self.t_g, self.s_g)
        p, h = _pose_at(s, self.xy, self.s_nodes)
        out = (tt < self.t0) | (tt > self.t1)
        p[out] = np.nan
        return s, p, h

    def grid(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Poses on the shared conflict-check time grid k * GRID_DT: (k0, s, xy, heading,
        bounding box (4,) of the positions)."""
        g = getattr(self, "_grid", None)
        if g is None:
            k0 = int(np.ceil(self.t0 / GRID_DT))
            k1 = int(np.floor(self.t1 / GRID_DT))
            s, p, h = self.at(np.arange(k0, k1 + 1) * GRID_DT)
            box = np.array([p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()]) \
                if len(p) else np.array([np.inf, -np.inf, np.inf, -np.inf])
            g = self._grid = (k0, s, p, h, box)
        return g


GRID_DT = 0.2  # s, time step of the conflict checks


def _overlap(c1, h1, half1, c2, h2, half2) -> np.ndarray:
    """(T,) bool: oriented rectangles overlap (separating axis test), vectorised over time."""
    d = c2 - c1
    out = np.zeros(len(d), bool)
    reach = np.hypot(*half1) + np.hypot(*half2)
    with np.errstate(invalid="ignore"):
        near = np.flatnonzero(np.einsum("ij,ij->i", d, d) < reach * reach)  # NaN -> False
    if len(near) == 0:
        return out
    d, h1, h2 = d[near], h1[near], h2[near]
    u1 = np.stack([np.cos(h1), np.sin(h1)], -1)
    v1 = np.stack([-u1[:, 1], u1[:, 0]], -1)
    u2 = np.stack([np.cos(h2), np.sin(h2)], -1)
    v2 = np.stack([-u2[:, 1], u2[:, 0]], -1)
    sep = np.zeros(len(d), bool)
    for ax in (u1, v1, u2, v2):
        r1 = half1[0] * np.abs((u1 * ax).sum(1)) + half1[1] * np.abs((v1 * ax).sum(1))
        r2 = half2[0] * np.abs((u2 * ax).sum(1)) + half2[1] * np.abs((v2 * ax).sum(1))
        sep |= np.abs((d * ax).sum(1)) > r1 + r2
    out[near] = ~sep
    return out


def _first_conflict(me: Traj, others: list[Traj], margin: float) -> tuple[float, float] | None:
    """(time, my arc length) of the first overlap with an earlier-scheduled road user."""
    k0, s, p, h, box = me.grid()
    if len(s) == 0:
        return None
    k1 = k0 + len(s)
    half = (me.half[0] + margin, me.half[1] + 0.05)  # keep the margin mostly fore and aft
    reach = 6.0  # m: more than any two half-diagonals
    best = None
    for o in others:
        if not me.vehicle and not o.vehicle:
            continue  # pedestrians pass each other
        ok0, os_, op, oh, obox = o.grid()
        a, b = max(k0, ok0), min(k1, ok0 + len(os_))
        if a >= b or (best is not None and a >= best):
            continue
        if (obox[0] > box[1] + reach or obox[1] < box[0] - reach or obox[2] > box[3] + reach
                or obox[3] < box[2] - reach):
            continue
        hit = np.flatnonzero(_overlap(p[a - k0:b - k0], h[a - k0:b - k0], half,
                                      op[a - ok0:b - ok0], oh[a - ok0:b - ok0], o.half))
        if len(hit) and (best is None or a + hit[0] < best):
            best = a + int(hit[0])
    return None if best is None else (best * GRID_DT, float(s[best - k0]))


@dataclass
class TrafficConfig:
    """Knobs of the traffic model (recorded in scene.json extra.generator.traffic)."""

    population: dict  # class -> number of road users (paper: 43 / 12 / 28)
    mean_pause_s: dict  # class -> mean pause between visits, seconds
    warmup_s: float = 60.0  # simulate this long before frame 0 so the scene starts busy
    group_share: float = 0.0  # share of the pedestrians who walk in groups of two or three

    def to_dict(self) -> dict:
        d = {"population": dict(self.population), "mean_pause_s": dict(self.mean_pause_s),
             "warmup_s": self.warmup_s}
        if self.group_share:  # (only then: scenes without groups keep their scene.json)
            d["group_share"] = self.group_share
        return d


GROUP_SPACING = 0.7  # m, between neighbours of a group walking side by side
GROUP_LAG = 0.3      # m, how far a member walks ahead of or behind the group's centre, at most


def pedestrian_groups(share: float, slots: list[int], seed: int) -> dict[int, tuple[int, ...]]:
    """Which population members walk together: leader slot -> the group's slots (leader
    first), about ``share`` of ``slots`` in groups of two (70 %) or three. Its own random
    stream, so the traffic's stream is untouched when ``share`` is 0."""
    if share <= 0 or len(slots) < 2:
        return {}
    rng = np.random.default_rng([seed, 12])
    order = [int(x) for x in rng.permutation(slots)]
    n = int(round(share * len(order)))
    groups, i = {}, 0
    while n - i >= 2:
        size = 3 if n - i >= 3 and rng.random() < 0.3 else 2
        g = tuple(sorted(order[i:i + size]))
        groups[g[0]] = g
        i += size
    return groups


def simulate(cfg: TrafficConfig, n_frames: int, dt: float, seed: int,
             stats: dict | None = None) -> list[Visit]:
    """All visits that overlap frames [0, n_frames), sorted by first frame (deterministic).

    Road users are scheduled in order of start time; each yields to the ones scheduled before
    it (waits at its stop line or curb, or starts later) so that no two overlap. ``stats``, when
    given, receives counts: visits, and yields that gave up after MAX_YIELD_STEPS (those road
    users may overlap another one)."""
    rng = np.random.default_rng([seed, 11])
    t_end = n_frames * dt
    heap: list[tuple[float, int, str]] = []
    # population member (slot) k's class: cars, then bicyclists, then pedestrians
    slot_cls = [c for c in ("car", "bicyclist", "pedestrian")
                for _ in range(int(cfg.population.get(c, 0)))]
    groups = pedestrian_groups(cfg.group_share,
                               [k for k, c in enumerate(slot_cls) if c == "pedestrian"], seed)
    follows = {m for g in groups.values() for m in g[1:]}  # scheduled with their group's leader
    for k, cls in enumerate(slot_cls):
        t = -cfg.warmup_s + rng.uniform(0, cfg.mean_pause_s.get(cls, 30.0) + cfg.warmup_s)
        if k not in follows:
            heap.append((t, k, cls))
    heapq.heapify(heap)
    queue: dict[tuple, tuple[float, int]] = {}  # lane -> (green time the queue waits for, count)
    active: list[Traj] = []
    visits: list[Visit] = []
    gave_up = 0
    while heap:
        t0, slot, cls = heapq.heappop(heap)
        if t0 >= t_end:
            continue
        active = [a for a in active if a.t1 >= t0]
        members = groups.get(slot, (slot,))
        if cls == "pedestrian":
            tr, stride = _pedestrian_traj(rng, t0, active, len(members))
        else:
            tr, stride = _vehicle_traj(rng, cls, t0, active, queue)
        active.append(tr)
        gave_up += int(tr.gave_up)
        f0 = max(int(np.ceil(tr.t0 / dt - 1e-9)), 0)
        f1 = min(int(np.floor(tr.t1 / dt + 1e-9)), n_frames - 1)
        if f1 >= f0:
            frames = np.arange(f0, f1 + 1)
            if len(members) > 1:
                visits.extend(_group_visits(rng, tr, members, frames, dt, stride))
            else:
                s, p, h = tr.at(frames * dt)
                visits.append(Visit(cls, frames, p, h, 2 * np.pi * s / stride, tr.t0, slot))
        t_next = max(tr.t1, t0 + 1.0) + rng.exponential(cfg.mean_pause_s.get(cls, 30.0))
        heapq.heappush(heap, (t_next, slot, cls))
    visits.sort(key=lambda v: (int(v.frames[0]), v.t0))
    if stats is not None:
        stats.update(visits=len(visits), yield_gave_up=gave_up)
        if groups:
            stats.update(groups=len(groups), in_groups=sum(len(g) for g in groups.values()))
    return visits


YIELD_STEP = 1.0  # s
MAX_YIELD_STEPS = 90  # then the road user goes anyway (rare; counted in the scene's extra)


def _vehicle_traj(rng, cls, t0, active, queue) -> tuple[Traj, float]:
    bike = cls == "bicyclist"
    route, arm = vehicle_route(rng, bike)
    lane = (arm, bike, round(float(route.xy[0, 0]), 2), round(float(route.xy[0, 1]), 2))
    v_cruise = rng.uniform(4.0, 6.5) if bike else rng.uniform(8.0, 12.5)
    acc, dec = (1.0, 1.5) if bike else (2.0, 3.0)
    # footprint half sizes: about the largest shapes' length, typical widths (lane neighbours,
    # 1.35 m apart for a bicyclist beside a car in the outer lane, must not count as conflicts)
    half = (0.95, 0.3) if bike else (2.6, 0.95)
    gap = 2 * half[0] + 2.0
    assert route.stop_s is not None  # a vehicle's route has a stop line
    stop_s = route.stop_s - half[0]  # the centre's arc length when the front is at the line
    shift = extra = 0.0
    s_free, t_free = _profile(route, v_cruise, acc, dec, None)
    for _ in range(MAX_YIELD_STEPS):
        start = t0 + shift
        t_arr = start + float(np.interp(stop_s, s_free, t_free))
        g = green_start(arm, t_arr)
        red = g > t_arr + 1e-6
        n_ahead = 0
        if red or extra > 0:
            qg, qn = queue.get(lane, (None, 0))
            n_ahead = qn if (red and qg == g) else 0
            stop = max(stop_s - n_ahead * gap, 1.0)
            s_g, t_g = _profile(route, v_cruise, acc, dec, stop)
            wait = g + 0.8 + 1.2 * n_ahead - (start + float(np.interp(stop, s_g, t_g))) if red else 0.0
            s_g, t_g = _hold(s_g, t_g, stop, max(wait, 0.0) + extra)
        else:
            stop = stop_s
            s_g, t_g = s_free, t_free
        tr = Traj(start, s_g, t_g, route.xy, route.s, half, True)
        c = _first_conflict(tr, active, margin=0.3)
        if c is None:
            break
        tr.gave_up = True
        if c[1] < stop - 0.5:
            shift += YIELD_STEP   # the conflict is on the approach: arrive later
        else:
            extra += YIELD_STEP   # in or past the junction: wait longer at the stop line
    if red:
        queue[lane] = (g, n_ahead + 1)
    return tr, 1e9


def _pedestrian_traj(rng, t0, active, n: int = 1) -> tuple[Traj, float]:
    """A pedestrian's (or, ``n`` > 1, a group's centre's) trajectory and stride (m)."""
    nodes, _ = pedestrian_route(rng)
    # sideways offset from the walking line: not too near the road, where turning bicyclists
    # pass (a group's centre: its outer members inside the same band)
    w = GROUP_SPACING * (n - 1) / 2
    xy = offset_polyline(densify(nodes, 0.5), rng.uniform(-0.6 + w, 1.1 - w))  # groups of <= 3
    s_nodes = arc_lengths(xy)
    # wait at the curb: the last point at least 0.6 m inside the sidewalk before each crossing
    d = J.curb_distance(xy)
    leave = np.flatnonzero((d[:-1] > 0) & (d[1:] <= 0))
    inside = np.flatnonzero(d > 0.6)
    s_wait = np.array([s_nodes[inside[inside <= i][-1]] for i in leave if (inside <= i).any()])
    speed = rng.uniform(1.05, 1.6)
    stride = rng.uniform(1.2, 1.5)
    # holds: at the curb before each crossing; sometimes a pause anywhere; some standers
    holds = [[float(sw), float(rng.uniform(0.0, 8.0))] for sw in s_wait]
    u = rng.random()
    # standing still happens on the sidewalk, never on the road
    walk = s_nodes[J.curb_distance(xy) > 0.5]
    if u < 0.12 and len(walk):      # a stander: stays for most of the visit
        holds.append([float(walk[rng.integers(len(walk))]), float(rng.uniform(40.0, 150.0))])
    elif u < 0.35 and len(walk):    # a pause: chatting, looking at a phone
        holds.append([float(walk[rng.integers(len(walk))]), float(rng.uniform(5.0, 30.0))])
    holds.sort()
    shift = 0.0
    for _ in range(MAX_YIELD_STEPS):
        s_g, t_g = s_nodes.copy(), s_nodes / speed
        for s_h, dwell in holds:
            s_g, t_g = _hold(s_g, t_g, s_h, dwell)
        t_g = t_g + np.arange(len(t_g)) * 1e-9  # strictly increasing for interpolation
        tr = Traj(t0 + shift, s_g, t_g, xy, s_nodes,
                  (0.2, 0.3) if n == 1 else (0.2 + GROUP_LAG, 0.3 + w), False)
        c = _first_conflict(tr, active, margin=0.2)
        if c is None:
            break
        tr.gave_up = True
        # wait longer at the last curb before the conflict, or start later
        before = [h for h in holds if h[0] <= c[1] - 0.3]
        if before:
            before[-1][1] += YIELD_STEP
        else:
            shift += YIELD_STEP
    return tr, stride


def _group_visits(rng, centre: Traj, members: tuple[int, ...], frames: np.ndarray, dt: float,
                  stride: float) -> list[Visit]:
    """The visits of a group walking ``centre``'s trajectory as a formation that turns with
    the centre's heading: member i shifted across it by (i - (n-1)/2) * GROUP_SPACING (places
    shuffled) and along it by a lag of its own (up to GROUP_LAG ahead or behind); each its own
    stride (the leader the centre's). A rigid formation, not offset copies of the path: those
    loop at the crossings' sharp corners and would walk neighbours into each other."""
    n = len(members)
    s, p_c, h = centre.at(frames * dt)
    u = np.column_stack([np.cos(h), np.sin(h)])
    v = np.column_stack([-u[:, 1], u[:, 0]])
    place = rng.permutation(n)
    out = []
    for i, m in enumerate(members):
        lag = rng.uniform(-GROUP_LAG, GROUP_LAG)
        p = p_c + (place[i] - (n - 1) / 2) * GROUP_SPACING * v + lag * u
        own = stride if i == 0 else rng.uniform(1.2, 1.5)
        out.append(Visit("pedestrian", frames, p, h, 2 * np.pi * (s + lag) / own, centre.t0, m))
    return out
