"""Routes through the junction: lanes and turns of cars and bicyclists, the sidewalk and
crosswalk graph of pedestrians, and the two-phase traffic signal. Units: metres, seconds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seg2pose.synth import junction as J

GREEN, ALL_RED = 18.0, 3.0  # s, signal timing; N-S green first, then E-W
CYCLE = 2 * (GREEN + ALL_RED)
TURN_A = J.ROAD_HALF + J.CORNER_R  # m from the centre where turns start and end
STOP_A = J.ROAD_HALF + J.CROSSWALK[1] + 1.0  # m, the stop line


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


def arc_lengths(xy: np.ndarray) -> np.ndarray:
    """Distance along a polyline (K, 2) at each vertex (K,), metres."""
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
        b_in = J.ROAD_HALF - 0.4
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
    s = arc_lengths(xy)
    vmax = np.full(len(xy), np.inf)
    if mv != "straight":
        vmax[len(p_in) - 1:len(p_in) + len(mid) - 1] = v_turn
    stop_s = J.STAGE - STOP_A
    return Route(xy, s, vmax, stop_s=stop_s, shared_s=J.STAGE - TURN_A), arm


# --- pedestrians: a graph of sidewalk lines and crosswalks -------------------------------------
_C = J.ROAD_HALF + J.SIDEWALK / 2      # walking line's distance from the arm axis
_X = J.ROAD_HALF + sum(J.CROSSWALK) / 2  # crosswalk centre along the arm


def _ped_nodes() -> tuple[dict, dict]:
    nodes: dict = {}
    edges: dict = {}
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


def offset_polyline(xy: np.ndarray, off: float) -> np.ndarray:
    """Shift a polyline sideways by ``off`` metres (to the left of the walking direction)."""
    t = np.gradient(xy, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    return xy + off * np.stack([-t[:, 1], t[:, 0]], 1)


def densify(xy: np.ndarray, step: float) -> np.ndarray:
    """Resample a polyline (K, 2) with vertices at most ``step`` metres apart (keeps corners)."""
    out = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)
