"""What a recording or an export shows: the runs, the frame range, the cameras and how often
images (masks, video) are logged. Shared by ``recording``/``session`` (Rerun) and
``mcap_export`` (MCAP), so both make the same choices from the same inputs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from s2p_review.runs import Run, load_run, scene_last_frame
from seg2pose.core.errors import InputError
from seg2pose.io.scene import Scene

IMAGE_BUDGET_PX = 160e6  # pixels of masks (and of video) logged by default: a few MB of output


def auto_every(n_frames: int, cams: list[str], scene: Scene, budget_px: float = IMAGE_BUDGET_PX) -> int:
    """The smallest cadence k that keeps n_frames / k images per camera within ``budget_px``."""
    px = sum(scene.cameras[c].width * scene.cameras[c].height for c in cams) * n_frames
    return max(1, int(np.ceil(px / budget_px)))


@dataclass(frozen=True)
class Cadence:
    """Log masks / video on every ``masks``-th / ``video``-th frame of the range (counted from
    its first frame). ``reduced``: the kinds ("masks", "video") whose automatic cadence is above
    1, so that the caller can tell the user why frames are missing."""

    masks: int = 1
    video: int = 1
    reduced: tuple[str, ...] = ()

    def notes(self) -> list[str]:
        return [f"{what}: one frame in {getattr(self, what)} (keeps the file small)"
                for what in self.reduced]

    def has_mask(self, frame: int, first: int) -> bool:
        return (frame - first) % self.masks == 0


def resolve_cadence(scene: Scene, first: int, last: int, cams: list[str],
                    mask_every: int | None = None, video_every: int | None = None,
                    masks: bool = True, video: bool = True,
                    budget_px: float = IMAGE_BUDGET_PX) -> Cadence:
    """The cadence for frames first..last of ``cams``; None = automatic (every frame while the
    images stay within IMAGE_BUDGET_PX pixels, else the smallest k that does)."""
    n = last - first + 1
    has_video = any(scene.video_path(c) is not None for c in cams)
    out, reduced = {}, []
    for what, k, wanted in (("masks", mask_every, masks), ("video", video_every, video and has_video)):
        if k is None:
            k = auto_every(n, cams, scene, budget_px)
            if k > 1 and wanted:
                reduced.append(what)
        if int(k) < 1:
            raise InputError(f"the {what} cadence must be >= 1, got {k}", field=f"{what}_every")
        out[what] = int(k)
    return Cadence(out["masks"], out["video"], tuple(reduced))


def resolve_frames(scene: Scene, runs: list[Run], frames: tuple[int, int] | None
                   ) -> tuple[int, int]:
    """The frame range to show, inclusive: ``frames`` when given (clipped to the scene's last
    frame), else the runs' frames, else the scene's."""
    last_scene = scene_last_frame(scene)
    if frames is not None:
        a, b = int(frames[0]), int(frames[1])
        if a < 0 or b < a:
            raise InputError(f"bad frame range {a}:{b}; expected A:B with 0 <= A <= B", field="frames")
        if last_scene is not None and a > last_scene:
            raise InputError(f"frame range {a}:{b} starts beyond the scene's last frame {last_scene}",
                             field="frames")
        return a, b if last_scene is None else min(b, last_scene)
    ranges = [r.frame_range for r in runs if r.frame_range is not None]
    if ranges:
        return min(a for a, _ in ranges), max(b for _, b in ranges)
    if last_scene is None:
        raise InputError("the scene has no masks, ground truth or splits, and no run was given: "
                         "nothing to show over time", file=scene.root)
    return 0, last_scene


def choose_cameras(scene: Scene, runs: list[Run], cameras: list[str] | None) -> list[str]:
    """``cameras`` (checked against the scene), else the cameras the runs used, else all."""
    if cameras:
        unknown = [c for c in cameras if c not in scene.cameras]
        if unknown:
            raise InputError(f"unknown cameras {unknown}; the scene has {sorted(scene.cameras)}",
                             field="cameras")
        return list(cameras)
    used = {c for r in runs for c in r.cameras}
    return [c for c in scene.cameras if c in used] if used else list(scene.cameras)


def load_runs(scene: Scene, paths: list[Path]) -> list[Run]:
    """Load and check run folders; two runs with one folder name get distinct entity names."""
    last_scene = scene_last_frame(scene)
    loaded = [load_run(Path(p), scene, last_scene) for p in paths]
    names = [r.name for r in loaded]
    return [dataclasses.replace(r, name=f"{r.name}_{i}") if names.count(r.name) > 1 else r
            for i, r in enumerate(loaded)]


@dataclass(frozen=True)
class Selection:
    """Everything a recording or export shows: runs, frames first..last, cameras, cadence."""

    runs: list[Run]
    first: int
    last: int
    cameras: list[str]
    cadence: Cadence

    @property
    def n_frames(self) -> int:
        return self.last - self.first + 1


def select(scene: Scene, runs: list[Path], frames: tuple[int, int] | None = None,
           cameras: list[str] | None = None, mask_every: int | None = None,
           video_every: int | None = None, masks: bool = True, video: bool = True) -> Selection:
    """Load the runs and settle frames, cameras and cadence (see the functions above)."""
    loaded = load_runs(scene, runs)
    first, last = resolve_frames(scene, loaded, frames)
    cams = choose_cameras(scene, loaded, cameras)
    cad = resolve_cadence(scene, first, last, cams, mask_every, video_every, masks, video)
    return Selection(loaded, first, last, cams, cad)
