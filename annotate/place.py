"""Placing road users from what the cameras see (a mixin of ``Project``): a pixel, a clicked
mask (its normal position, or the Seg2Pose estimate of a run), and pre-annotation from a run.

A pixel is turned into a camera ray and intersected with the ground surface raised by the
clicked point's height above the ground (0 for the ground contact point, the default; the
class's default height for a click on a mask's centre) — ``GroundSurface.intersect_rays``.
"""

from __future__ import annotations

import numpy as np

from annotate.edits import ProjectState
from annotate.estimates import MaskIndex
from annotate.model import EditError, keyframe_row, mark_spans
from annotate.presence import annotated_run_tracks, plan
from seg2pose.geometry.ground import miss_reasons


def pixel_to_ground(camera, ground, uv, height: float = 0.0) -> tuple[float, float]:
    """The ground position (x, y) metres below the point seen at pixel ``uv`` (2,) of
    ``camera``, that point being ``height`` metres above the ground surface."""
    uv = np.asarray(uv, dtype=np.float64).reshape(1, 2)
    if not np.all(np.isfinite(uv)):
        raise EditError(f"pixel must be finite numbers, got {uv[0].tolist()}")
    if not camera.in_image(uv)[0]:
        raise EditError(f"pixel ({uv[0, 0]:.1f}, {uv[0, 1]:.1f}) lies outside camera "
                        f"{camera.name}'s {camera.width}x{camera.height} image")
    X, status = ground.intersect_rays(camera.center, camera.unproject(uv), float(height))
    if not np.isfinite(X[0, 0]):
        raise EditError(f"the ray through pixel ({uv[0, 0]:.1f}, {uv[0, 1]:.1f}) of camera "
                        f"{camera.name} misses the ground: {miss_reasons(status)[0]}")
    return float(X[0, 0]), float(X[0, 1])


def motion_headings(xy: np.ndarray, heading: np.ndarray, min_step: float = 0.3) -> np.ndarray:
    """Headings (K,) for keyframes at xy (K, 2): the given ones where finite, else the direction
    to the next keyframe (from the previous one for the last) when that is more than
    ``min_step`` metres away, else the nearest filled one, else 0."""
    h = np.asarray(heading, dtype=np.float64).copy()
    d = np.diff(xy, axis=0)
    step = np.linalg.norm(d, axis=1)
    ang = np.arctan2(d[:, 1], d[:, 0])
    for k in np.flatnonzero(~np.isfinite(h)):
        if k < len(d) and step[k] > min_step:
            h[k] = ang[k]
        elif k > 0 and step[k - 1] > min_step:
            h[k] = ang[k - 1]
    ok = np.flatnonzero(np.isfinite(h))
    if not len(ok):
        return np.zeros(len(h))
    idx = np.arange(len(h))
    nearest = ok[np.abs(idx[:, None] - ok[None, :]).argmin(axis=1)]
    return np.where(np.isfinite(h), h, h[nearest])


class PlacementMixin(ProjectState):
    """Placement edits of ``Project``; every one returns a ``Change``."""

    @property
    def masks(self) -> MaskIndex:
        if getattr(self, "_masks", None) is None:
            self._masks = MaskIndex(self.scene)
        return self._masks

    def _camera(self, camera: str):
        if camera not in self.scene.cameras:
            raise EditError(f"unknown camera {camera!r}; the scene has {', '.join(self.scene.cameras)}")
        return self.scene.cameras[camera]

    def place_from_pixel(self, track_id: int, frame: int, camera: str, uv, height: float = 0.0,
                         heading: float | None = None):
        """Put the track's keyframe at ``frame`` where pixel ``uv`` (u, v) of ``camera`` meets
        the ground raised by ``height`` metres (see the module docstring). Heading: ``heading``
        if given, else a heading set there before, else along the motion (headings.py)."""
        t, f = self.track(track_id), self._frame(frame)
        x, y = pixel_to_ground(self._camera(camera), self.scene.ground, uv, height)
        return self._place(t, f, x, y, heading, (), "place_from_pixel")

    def place_from_mask(self, track_id: int, frame: int, camera: str, mask_track: int,
                        use_run: bool = True, heading: float | None = None):
        """Put the track's keyframe at ``frame`` on a clicked mask (identified by its track id
        in ``camera``'s masks): the run's Seg2Pose estimate of that road user when a run is
        loaded and has one (flag ``estimate``), else the mask's normal position (``normal``).
        Heading: ``heading`` if given; else the run's for a track's first keyframe; else the
        track's own there (interpolated, or along the motion: ``default_heading``)."""
        t, f = self.track(track_id), self._frame(frame)
        est = self._run.at(mask_track, f) if (use_run and self._run is not None) else None
        if est is not None:
            x, y, h = est
            return self._place(t, f, x, y, h if heading is None and not t.keyframes else heading,
                               ("estimate",), "place_from_mask")
        x, y, _ = self.masks.normal_position(camera, f, int(mask_track))
        return self._place(t, f, x, y, heading, ("normal",), "place_from_mask")

    def _place(self, t, f: int, x: float, y: float, heading, flags, name: str):
        self._free(t, f)
        heading, flags = self._heading(t.id, f, x, y, heading, flags)
        k = self._kf(t.id, f, x, y, heading, flags)
        return self._commit(name, [{"op": "set_keyframes", "id": t.id, "set": [keyframe_row(f, k)]}])

    def accept_estimate(self, track_id: int, frame: int | None = None, run_track: int | None = None,
                        every: int | None = None, frames: tuple[int, int] | None = None):
        """Take the run's estimate of road user ``run_track`` (default: the track's
        meta["run_track"], set when the track was made from a mask or by pre-annotation) as
        keyframes (flag ``estimate``): at ``frame``, or every ``every`` frames over ``frames``
        (first, last) plus the last estimate there. A track linked to no road user of the run
        is refused (its id is no run track's id: it would pull in another road user)."""
        t = self.track(track_id)
        if run_track is None and "run_track" not in t.meta:
            raise EditError(f"track {t.id} is linked to no road user of the run: make it from a "
                            "mask (mask mode, no track selected) or pre-annotate")
        rt = int(run_track if run_track is not None else t.meta["run_track"])
        if every is None:
            if frame is None:
                raise EditError("give a frame, or every= and frames=")
            f = self._frame(frame)
            est = self.run.at(rt, f)
            if est is None:
                raise EditError(f"the run has no estimate of road user {rt} at frame {f}")
            self._free(t, f)
            x, y, heading = est
            k = self._kf(t.id, f, x, y, heading, flags=("accepted", "estimate"))
            return self._commit("accept_estimate", [{"op": "set_keyframes", "id": t.id,
                                                     "set": [keyframe_row(f, k)]}])
        p = self._plan(rt, every, frames)
        if not p.keyframes:
            raise EditError(f"the run has no estimates of road user {rt} where a camera sees it "
                            f"in frames {frames}")
        spans = list(t.spans)
        for a, b, kind in p.spans:  # where the annotator keyframed, the annotator decides
            if not any(a <= f <= b for f, k in t.keyframes.items() if "estimate" not in k.flags):
                spans = mark_spans(spans, a, b, kind)
        drop = [f for f in t.keyframes if any(a <= f <= b for a, b, k in spans if k == "outside")]
        sets = [keyframe_row(f, self._kf(t.id, f, x, y, h, ("estimate",)))
                for f, x, y, h in p.keyframes if not any(a <= f <= b for a, b, k in spans
                                                         if k == "outside")]
        ops = [{"op": "set_fields", "id": t.id, "fields": {"spans": [list(s) for s in spans]}}]
        if drop:
            ops.insert(0, {"op": "set_keyframes", "id": t.id, "del": sorted(drop)})
        return self._commit("accept_estimates",
                            ops + [{"op": "set_keyframes", "id": t.id, "set": sets}])

    def _plan(self, rt: int, every: int, frames):
        """Keyframes and spans from run track ``rt``'s estimates (presence.py): every ``every``
        frames over ``frames`` (and the scene's frames), only where a camera sees it."""
        if int(every) < 1:
            raise EditError(f"every must be a whole number of frames >= 1, got {every!r}")
        est = self.run.track(rt)
        if frames is not None:
            est = est.in_frames((self._frame(frames[0]), self._frame(frames[1])))
        if self.frame_range is not None:
            est = est.in_frames(self.frame_range)
        seen = self.masks.seen(rt)
        if seen is None and self._run_ids_in_masks():
            seen = np.zeros(0, np.int64)  # the masks name the run's road users, never this one
        return plan(est, seen, int(every))

    def _run_ids_in_masks(self) -> bool:
        """Whether the masks' track ids are the run's (some run track has masks): then a run
        track without masks is seen nowhere; else presence is unknown and the run's own
        frames stand for it."""
        match = getattr(self, "_ids_match", None)
        if match is None:
            known = self.masks.presence()
            match = self._ids_match = any(int(r) in known for r in self.run.track_ids())
        return match

    def import_poses(self, table, every: int = 1, flags=("imported",), keep_ids: bool = True,
                     name: str = "import_poses"):
        """Keyframes from a pose table (another tool's annotation, a T-Analyst CSV, ground
        truth): one new track per track id with a keyframe at every ``every``-th row of it
        (and its last), class from the table, size from the table's l, w, h or the class. NaN
        headings (T-Analyst has none) point along the motion to the next keyframe. One
        undoable step; with ``keep_ids`` the tracks keep the table's ids (refused if taken)."""
        if int(every) < 1:
            raise EditError(f"every must be a whole number of frames >= 1, got {every!r}")
        order = np.lexsort((table.frame, table.track_id))
        table = table.take(order)
        ids = np.unique(table.track_id)
        taken = sorted(set(int(i) for i in ids) & set(self.tracks))
        if keep_ids and taken:
            raise EditError(f"track ids {taken[:10]} are taken already; import with "
                            "keep_ids=False to number the new tracks after the existing ones")
        next_id = max(self.tracks, default=0) + 1
        ops = []
        for rid in ids:
            rows = np.flatnonzero(table.track_id == rid)
            pick = rows[(np.arange(len(rows)) % int(every) == 0) | (np.arange(len(rows)) == len(rows) - 1)]
            tid = int(rid) if keep_ids else next_id
            next_id = max(next_id, tid) + 1
            if tid < 1:
                raise EditError(f"track id {tid} must be >= 1")
            cls = self._class(str(table.cls[pick[0]]))
            size = table.size[pick[0]] if table.size is not None and \
                np.all(np.isfinite(table.size[pick[0]])) else None
            frames = [self._frame(int(f)) for f in table.frame[pick]]
            if len(set(frames)) != len(frames):
                raise EditError(f"track {rid} has two rows in one frame")
            xy = table.xyz[pick, :2]
            hd = motion_headings(xy, table.heading[pick])
            kfs = [keyframe_row(f, self._kf(tid, f, x, y, h, flags)) for f, (x, y), h in zip(frames, xy, hd)]
            ops.append({"op": "put_track", "id": tid, "track": {
                "id": tid, "cls": cls, "size": list(self._size(size, cls)), "interp": None,
                "keyframes": kfs, "spans": [], "meta": {"source_track": int(rid)}}})
        if not ops:
            raise EditError("the table has no poses to import")
        return self._commit(name, ops)

    def preannotate(self, every: int = 25, frames: tuple[int, int] | None = None,
                    run_tracks=None, min_estimates: int = 2, skip_annotated: bool = False):
        """Pre-annotation: one new track per road user of the run (or of ``run_tracks``) with
        at least ``min_estimates`` estimates where a camera sees it in ``frames``: keyframes
        every ``every`` frames from its estimates and at both ends of each run of frames where
        its masks are (flag ``estimate``: unchecked), gaps marked occluded (short) or outside
        (presence.py), meta["run_track"] = its run id. One undoable step; ``change.created``
        holds the new ids. ``skip_annotated``: leave out road users already annotated: linked
        to a track (meta["run_track"]) or lying where a track is (``annotated_run_tracks``)."""
        run = self.run
        ids = run.track_ids() if run_tracks is None else [int(r) for r in run_tracks]
        if skip_annotated:
            linked = {int(t.meta["run_track"]) for t in self.tracks.values() if "run_track" in t.meta}
            linked |= annotated_run_tracks(run.table, self.poses())
            ids = [int(r) for r in ids if int(r) not in linked]
        next_id = max(self.tracks, default=0) + 1
        ops = []
        for rt in ids:
            p = self._plan(rt, every, frames)
            if len(p.keyframes) < min_estimates:
                continue
            cls = str(run.track(rt).cls[0])
            kfs = [keyframe_row(f, self._kf(next_id, f, x, y, h, ("estimate",)))
                   for f, x, y, h in p.keyframes]
            ops.append({"op": "put_track", "id": next_id, "track": {
                "id": next_id, "cls": cls, "size": list(self._size(None, cls)), "interp": None,
                "keyframes": kfs, "spans": [list(s) for s in p.spans], "reviewed": [],
                "meta": {"run_track": int(rt)}}})
            next_id += 1
        if not ops:
            raise EditError("the run has no road user with enough estimates to pre-annotate"
                            + (" that is not annotated already" if skip_annotated else ""))
        return self._commit("preannotate", ops)
