"""The annotation app's clicks (``Clicks``, a mixin of ``Controller``): a click in a camera
view's image or on the ground of the 3D view places the selected track's keyframe at the
current frame as the click mode says (``centre``, ``ground``; ``mask``: from the mask under
the pointer, making that road user's track when none is selected). Needs the controller's
``project``, ``frame``, ``selected``, ``click_mode``, ``lock``, ``touch`` and the edits of
``annotate.app.actions.Actions`` (``_need_track``, ``_edit``, ``_select``)."""

from __future__ import annotations

import math

import numpy as np

from annotate.app.actions import ControllerState
from seg2pose.core.errors import S2PError

GROUND_TOLERANCE = 0.25         # metres: a 3D click this close to the ground surface is on it


class Clicks(ControllerState):
    """The clicks of the viewer and the large camera's picture; what each did is returned as
    the panel's message (a click the controller cannot use says why)."""

    def click(self, camera: str | None, uv, hint_where: str = "") -> str:
        """A click in the viewer: ``camera`` the camera view it landed in (None: the 3D view or
        outside any image), ``uv`` the image pixel (x right, y down, pixel centres at +0.5).
        Places the selected track's keyframe at the current frame, as the click mode says."""
        with self.lock:
            self.touch()
            self.clicks += 1
            ok = uv is not None and all(v is not None for v in list(uv)[:2])
            self.last_click = {"camera": camera, "n": self.clicks,
                               "uv": [round(float(v), 2) for v in list(uv)[:2]] if ok else None}
            try:
                self.message = self._click(camera, uv, hint_where)
            except S2PError as e:
                self.message = str(e)
            return self.message

    def _click(self, camera, uv, where) -> str:
        if camera is None or uv is None or uv[0] is None or uv[1] is None:
            return (f"click ignored ({where or 'not on a camera image'}): click inside a camera "
                    "view's image to place the selected track")
        cam = self.project.scene.cameras[camera]
        u, v = float(uv[0]), float(uv[1])
        if not (0 <= u < cam.width and 0 <= v < cam.height):
            return f"click ignored: pixel ({u:.0f}, {v:.0f}) is outside camera {camera}'s image"
        if self.click_mode == "mask":
            return self._click_mask(camera, u, v)
        tid = self._need_track()
        t = self.project.track(tid)
        height = 0.0
        if self.click_mode == "centre":
            # a click on the middle of the road user is a click on its box's centre: half the
            # box's height above the ground (benches/annotate_accuracy.py compares this with
            # the class's default height of the normal position)
            height = float(t.size[2]) / 2
        self._edit(self.project.place_from_pixel, tid, self.frame, camera, (u, v), height=height)
        k = self.project.track(tid).keyframes[self.frame]
        return f"track {tid}: keyframe {self.frame} at ({k.x:.2f}, {k.y:.2f}) m"

    def _click_mask(self, camera: str, u: float, v: float) -> str:
        hit = self.mask_at(camera, u, v)
        if hit is None:
            return f"no mask under pixel ({u:.0f}, {v:.0f}) of camera {camera} in frame {self.frame}"
        mask_track, cls = hit
        p = self.project
        if self.selected is None:  # no track: the click makes the track of that road user
            ch = self._edit(p.create_track, cls, meta={"run_track": int(mask_track)})
            self._select(ch.track)
        else:  # never join another road user to the selected track silently
            t = p.track(self.selected)
            linked = t.meta.get("run_track")
            if linked is None and t.keyframes:
                return (f"refused: track {t.id} is linked to no road user and has keyframes; mask "
                        f"{mask_track} is road user {mask_track}. Esc (no track), then click the "
                        "mask to make its own track")
            if linked is not None and int(linked) != int(mask_track):
                return (f"refused: mask {mask_track} is road user {mask_track}, track {t.id} "
                        f"follows road user {linked}. Esc (no track), then click the mask to "
                        "make its own track")
            if linked is None:
                self._edit(p.set_meta, t.id, run_track=int(mask_track))
        tid = self.selected
        assert tid is not None  # selected (or made) above
        self._edit(p.place_from_mask, tid, self.frame, camera, mask_track)
        k = p.track(tid).keyframes[self.frame]
        return (f"track {tid}: keyframe {self.frame} from mask {mask_track} "
                f"({', '.join(k.flags) or 'placed'}) at ({k.x:.2f}, {k.y:.2f}) m")

    def click_world(self, xyz, entity: str = "") -> str:
        """A click in the 3D view at world point ``xyz`` (metres; None: the event carried no
        point): on the ground it places the selected track's keyframe there."""
        with self.lock:
            self.touch()
            self.clicks += 1
            ok = xyz is not None and len(xyz) >= 3 and all(
                v is not None and math.isfinite(float(v)) for v in list(xyz)[:3])
            self.last_click = {"camera": None, "n": self.clicks,
                               "xyz": [round(float(v), 3) for v in list(xyz)[:3]] if ok else None,
                               "uv": None}
            try:
                self.message = self._click_world(xyz if ok else None, entity)
            except S2PError as e:
                self.message = str(e)
            return self.message

    def _click_world(self, xyz, entity: str) -> str:
        if xyz is None:
            return ("click ignored: the 3D view did not say which point was clicked; click the "
                    "ground (grey mesh) or a camera view's image")
        x, y, z = (float(v) for v in list(xyz)[:3])
        g = float(self.project.scene.ground.height(np.array([[x, y]]))[0])
        if abs(z - g) > GROUND_TOLERANCE:
            return (f"click ignored: that point ({entity or 'an object'}) is {z - g:+.2f} m from "
                    "the ground; click the ground itself to place a keyframe")
        tid = self._need_track()
        self._edit(self.project.set_keyframe, tid, self.frame, x, y)
        return f"track {tid}: keyframe {self.frame} at ({x:.2f}, {y:.2f}) m (3D view)"

    def mask_at(self, camera: str, u: float, v: float) -> tuple[int, str] | None:
        """(mask track id, class name) of the topmost mask of ``camera`` covering pixel (u, v)
        in the current frame, or None."""
        from pycocotools import mask as rle

        t = self.project.masks.table(camera)
        sel = np.flatnonzero(t.frame == self.frame)
        if not len(sel):
            return None
        col, row = int(u), int(v)
        by_id = self.project.scene.class_by_id()
        for i in sel[::-1]:  # later masks are painted over earlier ones
            m = rle.decode({"size": [t.height, t.width], "counts": t.rles[i]})
            if m[row, col]:
                spec = by_id.get(int(t.class_id[i]))
                return int(t.track_id[i]), spec.name if spec else self.new_class
        return None


    # --- dragging the box in the large camera's picture (frame_view.py) ---------------------------
    def _ground_at(self, camera: str, uv) -> tuple[float, float]:
        from annotate.place import pixel_to_ground

        cam = self.project.scene.cameras[camera]
        return pixel_to_ground(cam, self.project.scene.ground, (float(uv[0]), float(uv[1])), 0.0)

    def drag(self, camera: str, uv0, uv1) -> str:
        """The selected box's base dragged from pixel ``uv0`` to ``uv1`` of ``camera``: the
        pose at the current frame moves on the ground by the difference of the two ground
        points (a keyframe, checked: its estimate flag goes)."""
        with self.lock:
            self.touch()
            try:
                tid = self._need_track()
                (x0, y0), (x1, y1) = self._ground_at(camera, uv0), self._ground_at(camera, uv1)
                x, y, _ = self.project.pose_at(tid, self.frame)
                self._edit(self.project.move_keyframe, tid, self.frame, x + x1 - x0, y + y1 - y0)
                self.message = (f"track {tid}: moved by ({x1 - x0:+.2f}, {y1 - y0:+.2f}) m at "
                                f"frame {self.frame}")
            except S2PError as e:
                self.message = str(e)
            return self.message

    def rotate_to(self, camera: str, uv) -> str:
        """The selected box's handle dragged to pixel ``uv``: the pose at the current frame
        turns to face the ground point there."""
        with self.lock:
            self.touch()
            try:
                tid = self._need_track()
                gx, gy = self._ground_at(camera, uv)
                x, y, _ = self.project.pose_at(tid, self.frame)
                h = math.atan2(gy - y, gx - x)
                self._edit(self.project.move_keyframe, tid, self.frame, x, y, h)
                self.message = f"track {tid}: heading {math.degrees(h):.1f}° at frame {self.frame}"
            except S2PError as e:
                self.message = str(e)
            return self.message

    def footprint_now(self, tid: int) -> tuple[float, float, float, float, np.ndarray] | None:
        """Track ``tid`` at the current frame: x, y (m), heading (rad), the ground's z there (m)
        and its footprint's four corners (4, 2) in metres; None where it has no pose."""
        from seg2pose.safety.footprints import corners as footprint

        try:
            x, y, h = self.project.pose_at(tid, self.frame)
        except S2PError:
            return None
        size = self.project.track(tid).size
        z = float(self.project.scene.ground.height(np.array([[x, y]]))[0])
        foot = footprint(np.array([[x, y]]), np.array([h]), np.array([size]))[0]
        return x, y, h, z, foot

    def box_handles(self, camera: str) -> dict | None:
        """The selected track's base at the current frame in ``camera``'s image: {"base": four
        corners [[u, v]...], "handle": [u, v] a point ahead of its front} (None: no pose
        here, or not wholly in front of the camera)."""
        tid = self.selected
        if tid is None or tid not in self.project.tracks:
            return None
        now = self.footprint_now(tid)
        if now is None:
            return None
        x, y, h, z, foot = now
        t = self.project.track(tid)
        ahead = t.size[0] / 2 + max(0.6, 0.25 * t.size[0])
        pts = np.vstack([np.c_[foot, np.full(4, z)],
                         [[x + ahead * math.cos(h), y + ahead * math.sin(h), z]]])
        uv, _, front = self.project.scene.cameras[camera].project_points(pts)
        if not front.all():
            return None
        return {"base": np.round(uv[:4], 1).tolist(), "handle": np.round(uv[4], 1).tolist()}
