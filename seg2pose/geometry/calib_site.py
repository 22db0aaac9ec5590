"""A new site's calibration from clicked pairs, as one step: the ground from the known
elevations (ground_fit.py), unknown elevations taken from it, the cameras solved (one device's
cameras together, calibrate.py), and what the result costs in metres (calib_quality.py): per
pair errors, warnings naming disagreeing pairs, the suggested next point, and a report (a
JSON-ready dict and its text).

Units: pixels, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seg2pose.core.errors import InputError
from seg2pose.geometry import calib_quality as Q
from seg2pose.geometry.calibrate import PairSet, Solution, SolveOptions, solve_group
from seg2pose.geometry.ground_fit import GroundFit, ground_from_elevations


@dataclass
class SiteInput:
    """pairs: camera -> {"uv" (N, 2), "X" (N, 3) with z NaN where unknown, "names"};
    sizes: camera -> (width, height); devices: lists of cameras solved together (sharing
    intrinsics; default: each camera alone); survey: (n, 3) further known points (z NaN where
    unknown) for the ground; opts: SolveOptions."""

    pairs: dict[str, dict]
    sizes: dict[str, tuple[int, int]]
    devices: list[list[str]] | None = None
    survey: np.ndarray | None = None
    opts: SolveOptions = field(default_factory=SolveOptions)


@dataclass
class CameraReport:
    solution: Solution
    ground_err_m: np.ndarray
    warnings: list[str]
    suggestion: tuple[np.ndarray, np.ndarray, float] | None
    maps: Q.CostMaps


@dataclass
class SiteResult:
    cameras: dict[str, CameraReport]
    ground: GroundFit
    notes: list[str]

    def camera_dicts(self) -> list[dict]:
        return [r.solution.camera.to_dict() for r in self.cameras.values()]

    def report(self) -> dict:
        """JSON-ready: per camera focal, its sd, field of view, centre, noise scale, per pair
        errors, warnings, suggestion; the ground's summary."""
        cams = {}
        for name, r in self.cameras.items():
            s, cam = r.solution, r.solution.camera
            mpp, sd = r.maps.m_per_px, r.maps.sd_m
            road = r.maps.road & ~r.maps.extrapolating
            cams[name] = {
                "focal_px": float(cam.K[0, 0]), "focal_sd_px": float(s.focal_sd),
                "hfov_deg": float(np.degrees(2 * np.arctan(cam.width / 2 / cam.K[0, 0]))),
                "center": cam.center.tolist(), "noise_scale": float(s.scale),
                "pairs_used": int(s.used.sum()), "pairs": len(s.used),
                "rms_px": float(np.sqrt(np.mean(np.sum(s.residual_px[s.used] ** 2, axis=1)))),
                "median_m_per_px_in_hull": _nanmed(mpp[road]),
                "median_position_sd_m_in_hull": _nanmed(sd[road]),
                "median_position_sd_m_extrapolating": _nanmed(sd[r.maps.road & r.maps.extrapolating]),
                "points": [{"name": n, "u": float(uv[0]), "v": float(uv[1]), "x": float(X[0]),
                            "y": float(X[1]), "z": float(X[2]), "used": bool(u),
                            "error_px": float(np.linalg.norm(e)), "error_m": float(g),
                            "sigmas": float(m * s.scale)}
                           for n, uv, X, u, e, g, m in zip(s.pairs.names, s.pairs.uv, s.pairs.X, s.used,
                                                           s.residual_px, r.ground_err_m, s.mahalanobis,
                                                           strict=True)],
                "warnings": r.warnings,
                "suggested_next": None if r.suggestion is None else {
                    "u": float(r.suggestion[0][0]), "v": float(r.suggestion[0][1]),
                    "x": float(r.suggestion[1][0]), "y": float(r.suggestion[1][1]),
                    "variance_removed": float(r.suggestion[2])},
                "notes": s.notes,
            }
        g = self.ground
        return {"cameras": cams, "ground": {"summary": g.summary, "coef": g.coef, "level": g.level,
                                            "residuals_m": g.residuals.tolist()},
                "notes": self.notes}

    def text(self) -> str:
        """The report as lines for a terminal."""
        rep = self.report()
        lines = []
        for name, c in rep["cameras"].items():
            lines.append(f"camera {name}: focal {c['focal_px']:.1f} px (sd {c['focal_sd_px']:.1f}; "
                         f"{c['hfov_deg']:.1f} deg across), centre "
                         f"({', '.join(f'{v:.2f}' for v in c['center'])}) m, {c['pairs_used']}/"
                         f"{c['pairs']} pairs, rms {c['rms_px']:.2f} px, noise scale "
                         f"{c['noise_scale']:.2f}")
            lines.append(f"  one pixel moves a normal position {c['median_m_per_px_in_hull']:.3f} m "
                         f"(median inside the pairs' hull); the calibration's own uncertainty "
                         f"{c['median_position_sd_m_in_hull']:.3f} m there, "
                         f"{c['median_position_sd_m_extrapolating']:.3f} m outside it")
            for p in c["points"]:
                flag = "" if p["used"] else "  (left out)"
                lines.append(f"  {p['name']:>12}: {p['error_px']:6.2f} px {p['error_m']:6.3f} m "
                             f"{p['sigmas']:5.1f} sd{flag}")
            if c["suggested_next"]:
                sn = c["suggested_next"]
                lines.append(f"  next point: pixel ({sn['u']:.0f}, {sn['v']:.0f}), about "
                             f"({sn['x']:.1f}, {sn['y']:.1f}) m; it would remove "
                             f"{100 * sn['variance_removed']:.0f} % of the road's position variance")
            lines += [f"  warning: {w}" for w in c["warnings"]]
            lines += [f"  note: {n}" for n in c["notes"]]
        lines.append(f"ground: {rep['ground']['summary']}")
        lines += [f"note: {n}" for n in rep["notes"]]
        return "\n".join(lines) + "\n"


def _nanmed(a: np.ndarray) -> float | None:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if len(a) else None


def calibrate_site(inp: SiteInput, maps_step: int = 16) -> SiteResult:
    """See the module doc."""
    unknown = [c for c in inp.pairs if c not in inp.sizes]
    if unknown:
        raise InputError(f"no image size for camera {unknown[0]!r}", field="image_size")
    known = [d["X"][np.isfinite(d["X"][:, 2])] for d in inp.pairs.values()]
    extent = [d["X"][:, :2] for d in inp.pairs.values()]
    if inp.survey is not None and len(inp.survey):
        known.append(inp.survey[np.isfinite(inp.survey[:, 2])])
        extent.append(inp.survey[:, :2])
    ground = ground_from_elevations(np.vstack(known) if known else np.empty((0, 3)), np.vstack(extent))
    notes = []
    sets: dict[str, PairSet] = {}
    for c, d in inp.pairs.items():
        X = d["X"].copy()
        miss = ~np.isfinite(X[:, 2])
        if miss.any():
            X[miss, 2] = ground.height(X[miss, :2])
            notes.append(f"{c}: {int(miss.sum())} pair(s) without elevation placed on the ground "
                         f"({ground.summary.split(' (')[0]})")
        w, h = inp.sizes[c]
        sets[c] = PairSet(c, w, h, d["uv"], X, list(d["names"]))
    groups = inp.devices or [[c] for c in inp.pairs]
    seen = [c for g in groups for c in g]
    for c in inp.pairs:
        if c not in seen:
            groups.append([c])
    reports = {}
    height = ground.height
    for g in groups:
        members = [c for c in g if c in sets]
        for sol in solve_group([sets[c] for c in members], inp.opts):
            gerr = Q.pair_ground_errors(sol)
            reports[sol.camera.name] = CameraReport(
                sol, gerr, Q.disagreeing(sol, gerr), Q.suggest_next(sol, inp.opts, height),
                Q.cost_maps(sol, height, step=maps_step))
    o = inp.opts
    notes.append(f"focal prior: log-normal around {o.focal_prior_px:.0f} px" if o.focal_prior_px else
                 f"focal prior: log-normal around a {o.fov_prior_deg:g} deg horizontal field of view, "
                 f"sigma {o.focal_log_sigma:g} in log f")
    return SiteResult({c: reports[c] for c in inp.pairs}, ground, notes)
