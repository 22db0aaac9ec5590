"""The calibration page's state: the frames, the aerial image with its georeference or the
survey table, the clicked pairs kept in an append-only journal (io/jsonl_log.py: crash-safe,
replayed on start), undo, the solve and the save.

Journal records: ``{"kind": "pair", "id": n, "camera", "u", "v", "x", "y", "z" (or null),
"name", "ax", "ay" (the aerial pixel, or null for a surveyed point)}`` and
``{"kind": "undo", "of": n}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import InputError, S2PError
from seg2pose.geometry.calib_site import SiteResult
from seg2pose.geometry.calibrate import SolveOptions
from seg2pose.io.calib_files import aerial_to_world, read_survey, read_world_file, two_point_georeference
from seg2pose.io.jsonl_log import AppendLog

JOURNAL_VERSION = 1


@dataclass
class PageArgs:
    """What ``s2p calibrate-camera`` passes to the page (see its options)."""

    source: Path | None
    aerial: Path | None
    world_file: Path | None
    reference: list[str]
    survey: Path | None
    cameras: list[str]
    sizes: dict
    out: Path | None
    devices: list[list[str]] | None
    opts: SolveOptions = field(default_factory=SolveOptions)
    force: bool = False
    port: int | None = None


def find_world_file(aerial: Path) -> Path | None:
    """The world file beside an aerial image: image.pgw / .jgw / .tfw / .wld / image.png.w."""
    ext = aerial.suffix.lower()
    cands = [aerial.with_suffix(ext[:2] + ext[-1] + "w"), aerial.with_suffix(".wld"),
             aerial.with_name(aerial.name + "w")]
    return next((p for p in cands if p.exists()), None)


def georeference(args: PageArgs) -> np.ndarray | None:
    """The aerial image's map (2, 3): its world file, or two --reference U,V,X,Y."""
    if args.aerial is None:
        return None
    if args.reference:
        if len(args.reference) != 2:
            raise InputError("give --reference twice (two aerial pixels with their world x, y)",
                             field="reference")
        vals = []
        for r in args.reference:
            try:
                v = [float(s) for s in r.split(",")]
                if len(v) != 4 or not np.all(np.isfinite(v)):
                    raise ValueError
            except ValueError:
                raise InputError(f"expected U,V,X,Y numbers, got {r!r}", field="reference") from None
            vals.append(v)
        P = np.array(vals)
        return two_point_georeference(P[:, :2], P[:, 2:])
    wf = args.world_file or find_world_file(args.aerial)
    if wf is None:
        raise InputError("no world file beside the aerial image; give --world-file or two --reference "
                         "U,V,X,Y", file=args.aerial)
    return read_world_file(wf)


class PageState:
    """Everything the page shows and changes; the journal is held open (its lock) until
    ``close``."""

    def __init__(self, args: PageArgs, journal: Path, sizes: dict, frames: dict):
        self.args = args
        self.sizes = sizes  # camera -> (w, h)
        self.frames = frames  # camera -> BGR image or None
        self.A = georeference(args)
        self.survey_names: list[str] = []
        self.survey: np.ndarray = np.empty((0, 3))
        if args.survey is not None:
            self.survey_names, self.survey = read_survey(args.survey)
        self.log = AppendLog(journal)
        if not self.log.records:
            self.log.append({"kind": "header", "version": JOURNAL_VERSION})
        self.solved: SiteResult | None = None  # the last solve
        self.pictures: dict[str, bytes] = {}

    # --- the pairs ------------------------------------------------------------------------------
    def pairs(self) -> list[dict]:
        """The pairs in force: every pair record not undone, in order."""
        undone = {r["of"] for r in self.log.records if r.get("kind") == "undo"}
        return [r for r in self.log.records if r.get("kind") == "pair" and r["id"] not in undone]

    def add_pair(self, camera: str, u: float, v: float, ax: float | None = None, ay: float | None = None,
                 survey: str | None = None, z: float | None = None) -> dict:
        """A pair from a frame pixel and an aerial pixel (or a surveyed point's name), with an
        optional elevation (metres; a surveyed point's own when not given)."""
        if camera not in self.sizes:
            raise InputError(f"unknown camera {camera!r}; the page has {sorted(self.sizes)}", field="camera")
        w, h = self.sizes[camera]
        if not (0 <= u <= w and 0 <= v <= h):
            raise InputError(f"pixel ({u:g}, {v:g}) is outside the {w}x{h} frame", field="u")
        if survey is not None:
            if survey not in self.survey_names:
                raise InputError(f"no surveyed point {survey!r}", field="survey")
            x, y, zs = self.survey[self.survey_names.index(survey)]
            z = z if z is not None else (None if np.isnan(zs) else float(zs))
            name = survey
        else:
            if self.A is None or ax is None or ay is None:
                raise InputError("a pair needs its aerial pixel (or a surveyed point)", field="ax")
            x, y = aerial_to_world(self.A, np.array([[ax, ay]], float))[0]
            name = None
        pid = 1 + max((r["id"] for r in self.log.records if r.get("kind") == "pair"), default=0)
        rec = {"kind": "pair", "id": pid, "camera": camera, "u": float(u), "v": float(v),
               "x": float(x), "y": float(y), "z": None if z is None else float(z),
               "name": name or f"p{pid}", "ax": ax, "ay": ay}
        self.log.append(rec)
        return rec

    def undo(self) -> dict | None:
        """Undo the last pair in force (None when there is none)."""
        live = self.pairs()
        if not live:
            return None
        rec = {"kind": "undo", "of": live[-1]["id"]}
        self.log.append(rec)
        return rec

    def pair_arrays(self) -> dict[str, dict]:
        """Camera -> {"uv", "X" (z NaN when unknown), "names"} of the pairs in force."""
        out: dict[str, dict] = {}
        for r in self.pairs():
            d = out.setdefault(r["camera"], {"uv": [], "X": [], "names": []})
            d["uv"].append([r["u"], r["v"]])
            d["X"].append([r["x"], r["y"], np.nan if r["z"] is None else r["z"]])
            d["names"].append(r["name"])
        return {c: {"uv": np.array(d["uv"]), "X": np.array(d["X"]), "names": d["names"]} for c, d in out.items()}

    # --- solve and save -------------------------------------------------------------------------
    def solve(self) -> str:
        """Solve the cameras with pairs; the report's text (pictures kept for the page)."""
        from seg2pose.eval.calib_picture import cost_picture
        from seg2pose.geometry.calib_site import SiteInput, calibrate_site

        pairs = self.pair_arrays()
        if not pairs:
            raise InputError("no pairs yet: click a point in the frame, then its partner")
        survey = self.survey if len(self.survey) else None
        self.solved = calibrate_site(SiteInput(pairs, {c: self.sizes[c] for c in pairs},
                                               self.args.devices, survey, self.args.opts))
        self.pictures = {c: cost_picture(r, self.frames.get(c)) for c, r in self.solved.cameras.items()}
        return self.solved.text()

    def save(self, scene=None) -> list[str]:
        """Write the last solve as the command would (calib.json at --out, or the scene's next
        version); lines saying where."""
        from seg2pose.io.calib_files import write_result

        if self.solved is None:
            raise S2PError("solve first")
        return write_result(self.solved, self.solved.text(), self.pictures, self.args.out, scene,
                            self.args.force)

    def close(self) -> None:
        self.log.close()
