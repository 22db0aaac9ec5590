"""The annotation app's controller and its Rerun logging, without a browser: clicks become
keyframes at the right place, actions and shortcuts do what their labels say, the page state
survives a reopen, a second page is read-only, bad clicks are ignored with a hint, and an edit
re-sends only the changed track."""

from __future__ import annotations

import numpy as np
import pytest

from annotate import Project
from annotate.app import controller as C
from annotate.app.actions import ACTIONS, SHORTCUTS
from annotate.app.controller import Controller


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from seg2pose.synth.generate import SynthOptions, generate_scene

    root = tmp_path_factory.mktemp("app") / "scene"
    generate_scene(root, SynthOptions(preset="small", frames=3, seed=1, video=False, progress=False, workers=1))
    return root


@pytest.fixture
def ctl(scene_dir):
    import shutil

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    c = Controller.open(scene_dir, cameras=["c1"])
    yield c
    c.close()


def _pixel(ctl, xy, height):
    """The pixel of camera c1 that sees the point ``height`` m over the ground at xy."""
    s = ctl.project.scene
    p = np.r_[xy, s.ground.height(np.asarray(xy, float)[None])[0] + height]
    uv, _, _ = s.cameras["c1"].project_points(p[None])
    return uv[0]


def test_every_action_has_a_unique_shortcut_and_a_handler():
    keys = [a.key for a in ACTIONS]
    assert len(keys) == len(set(keys))
    names = {a.name for a in ACTIONS}
    assert set(SHORTCUTS.values()) <= names
    for a in ACTIONS:
        if ":" not in a.name:
            assert hasattr(Controller, "_a_" + a.name), a.name
    # the list: frame steps, keyframe jumps, nudges 2/10/50 cm, rotations 1/5/15 degrees
    labels = " ".join(a.label for a in ACTIONS)
    for word in ("2 cm", "10 cm", "50 cm", "1°", "5°", "15°", "undo", "redo", "split", "merge",
                 "accept estimate", "occluded", "outside", "suggested"):
        assert word in labels, word


def test_click_places_keyframe_at_the_clicked_point(ctl):
    ctl.do("class:car")
    ctl.do("new_track")
    tid = ctl.selected
    from annotate.place import pixel_to_ground

    s = ctl.project.scene
    xy = pixel_to_ground(s.cameras["c1"], s.ground, (640.0, 420.0))  # a point in view
    ctl.project.set_size(tid, (4.0, 1.8, 1.6))  # centre mode: half the track's box height
    for mode, height in (("centre", 0.8), ("ground", 0.0)):
        ctl.click_mode = mode
        msg = ctl.click("c1", _pixel(ctl, xy, height))
        assert "keyframe 0" in msg
        k = ctl.project.track(tid).keyframes[0]
        assert np.hypot(k.x - xy[0], k.y - xy[1]) < 1e-6
    # journalled: a fresh read of the journal has it
    with Project.open(s.root, read_only=True) as p:
        assert p.track(tid).keyframes[0].x == pytest.approx(xy[0])


def test_bad_clicks_are_ignored_with_a_hint(ctl):
    assert "no track selected" in ctl.click("c1", (100.0, 100.0))
    ctl.do("new_track")
    seq = ctl.project.seq
    assert "click ignored" in ctl.click(None, [1.0, 2.0, 3.0], "world is not a camera view")
    assert "outside camera c1" in ctl.click("c1", (5000.0, 10.0))
    assert "click ignored" in ctl.click("c1", [None, None, None])
    assert ctl.project.seq == seq  # nothing journalled


def test_actions_move_frames_nudge_rotate_undo_redo(ctl):
    ctl.do("new_track")
    tid = ctl.selected
    ctl.project.set_keyframe(tid, 0, 1.0, -10.0, heading=0.0)
    ctl.project.set_keyframe(tid, 2, 2.0, -10.0, heading=0.0)
    ctl.do("next_keyframe")
    assert ctl.frame == 2
    ctl.do("prev_keyframe")
    assert ctl.frame == 0
    ctl.do(SHORTCUTS["d"])            # +x 10 cm
    ctl.do(SHORTCUTS["Shift+w"])      # +y 50 cm
    ctl.do(SHORTCUTS["Alt+a"])        # -x 2 cm
    k = ctl.project.track(tid).keyframes[0]
    assert (k.x, k.y) == pytest.approx((1.08, -9.5))
    ctl.do(SHORTCUTS["Shift+q"])      # +15 degrees
    assert np.degrees(ctl.project.track(tid).keyframes[0].heading) == pytest.approx(15)
    ctl.do("undo")
    ctl.do("undo")
    assert ctl.project.track(tid).keyframes[0].x == pytest.approx(1.1)
    ctl.do("redo")
    assert ctl.project.track(tid).keyframes[0].x == pytest.approx(1.08)
    ctl.do("fwd10")
    assert ctl.frame == ctl.frame_range[1] == 10  # clamped to the scene's frames
    ctl.do("back10")
    ctl.do("next_frame")
    assert ctl.frame == 1
    assert ctl.panel()["here"] == "interpolated"
    msg = ctl.do("next_suggestion")  # against the masks' normal positions (no run)
    assert msg.startswith("track ") or msg.startswith("no suggestions")


def test_spans_split_merge_and_interpolation(ctl):
    ctl.do("new_track")
    a = ctl.selected
    for f, x in ((0, 0.0), (1, 1.0), (2, 2.0)):
        ctl.project.set_keyframe(a, f, x, -10.0, heading=0.0)
    ctl.goto(1)
    ctl.do("occluded")
    assert ctl.project.track(a).spans == [(1, 1, "occluded")]
    ctl.do("visible")
    assert ctl.project.track(a).spans == []
    ctl.do("split")
    b = ctl.selected
    assert b != a and ctl.project.track(b).frames == [1, 2] and ctl.project.track(a).frames == [0]
    ctl.do(f"select:{a}")   # previous = b
    ctl.do("merge")         # b into a
    assert b not in ctl.project.tracks and ctl.project.track(a).frames == [0, 1, 2]
    before = ctl.project.interpolation(a)
    ctl.do("interpolation")
    assert ctl.project.interpolation(a) != before


def test_edit_notifies_only_the_changed_track(ctl):
    ctl.do("new_track")
    a = ctl.selected
    ctl.do("new_track")
    b = ctl.selected
    ctl.project.set_keyframe(a, 0, 0.0, -10.0, heading=0.0)
    ctl.project.set_keyframe(b, 0, 5.0, -10.0, heading=0.0)
    seen = []
    ctl.on_tracks.append(lambda ids, sel: seen.append(ids))
    ctl.do("nudge:0.1:0")
    assert seen == [{b}]
    ctl.do(f"select:{a}")  # selection: the old and the new selected track are redrawn
    assert seen[-1] == {a, b}


def test_reopen_restores_selection_and_frame(scene_dir):
    import shutil

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    c = Controller.open(scene_dir)
    c.do("new_track")
    c.do("new_track")
    c.goto(7)
    c.do("click_mode")
    sel, mode = c.selected, c.click_mode
    c.close()
    d = Controller.open(scene_dir)
    try:
        assert (d.selected, d.frame, d.click_mode) == (sel, 7, mode)
        assert len(d.project.tracks) == 2
    finally:
        d.close()


def test_second_page_is_read_only_until_the_first_goes_quiet(scene_dir, monkeypatch):
    import shutil

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    first = Controller.open(scene_dir)
    second = Controller.open(scene_dir)
    try:
        assert not first.read_only and second.read_only
        assert "another tab" in second.read_only_reason
        assert "another tab" in second.do("new_track")
        assert len(second.project.tracks) == 0
        # the first page falls silent: a new page takes the project over
        monkeypatch.setattr(C, "HOLD_SECONDS", 0.0)
        third = Controller.open(scene_dir)
        assert not third.read_only
        third.do("new_track")
        assert len(third.project.tracks) == 1
        third.close()
    finally:
        second.close()
        first.close()


def test_mask_mode_uses_the_mask_under_the_click(ctl):
    t = ctl.project.masks.table("c1")
    i = int(np.flatnonzero(t.frame == 0)[0])
    from pycocotools import mask as rle

    m = rle.decode({"size": [t.height, t.width], "counts": t.rles[i]})
    rows, cols = np.nonzero(m)
    u, v = cols[len(cols) // 2] + 0.5, rows[len(rows) // 2] + 0.5
    assert ctl.mask_at("c1", u, v)[0] == int(t.track_id[i])
    ctl.click_mode = "mask"
    msg = ctl.click("c1", (u, v))  # no track selected: one is made of the mask's class
    assert "from mask" in msg
    tid = ctl.selected
    x, y, _ = ctl.project.masks.normal_position("c1", 0, int(t.track_id[i]))
    k = ctl.project.track(tid).keyframes[0]
    assert (k.x, k.y) == pytest.approx((x, y)) and "normal" in k.flags
    assert "no mask under" in ctl.click("c1", (1.0, 1.0))
    # another road user's mask while this track is selected: refused, naming both, no keyframe
    others = [j for j in np.flatnonzero(t.frame == 0) if t.track_id[j] != t.track_id[i]]
    j = others[0]
    m2 = rle.decode({"size": [t.height, t.width], "counts": t.rles[j]})
    r2, c2 = np.nonzero(m2 & ~m)
    msg = ctl.click("c1", (c2[len(c2) // 2] + 0.5, r2[len(r2) // 2] + 0.5))
    assert msg.startswith("refused") and f"mask {t.track_id[j]}" in msg and f"track {tid}" in msg
    assert list(ctl.project.tracks) == [tid] and len(ctl.project.track(tid).keyframes) == 1
    # Esc: no track; the same click makes that road user's own track
    ctl.do("deselect")
    assert ctl.selected is None
    ctl.click("c1", (c2[len(c2) // 2] + 0.5, r2[len(r2) // 2] + 0.5))
    assert ctl.selected != tid and ctl.project.track(ctl.selected).meta["run_track"] == t.track_id[j]


def test_class_keys_delete_with_confirmation_and_headings_shown(ctl):
    classes = [c.name for c in ctl.project.scene.classes]
    ctl.do("class_key:2")
    assert ctl.new_class == classes[1]
    ctl.do("new_track")
    tid = ctl.selected
    assert ctl.project.track(tid).cls == classes[1]
    ctl.do("class_key:1")  # with a track selected: that track changes class (and size)
    t = ctl.project.track(tid)
    assert t.cls == classes[0] and t.size == tuple(ctl.project.scene.class_sizes()[classes[0]])
    assert "classes" in ctl.do(f"class_key:{len(classes) + 1}")
    ctl.click_mode = "ground"
    ctl.click("c1", _pixel(ctl, (0.0, 0.0), 0.0))
    assert [k["heading_mode"] for k in ctl.keyframe_rows()] == ["auto"]
    layouts = []
    ctl.on_layout.append(layouts.append)
    assert "camera c1 large" in ctl.do("best_camera") and layouts == ["c1"]
    ctl.do("large_camera")
    assert ctl.large_camera == "c1" and layouts == ["c1", "c1"]
    ctl.do("rotate:5")
    assert [k["heading_mode"] for k in ctl.keyframe_rows()] == ["set"]
    ctl.do("goto:2")
    assert ctl.frame == 2 and "not a frame number" in ctl.do("goto:")
    assert "Shift+Delete again" in ctl.do("delete_track")
    assert tid in ctl.project.tracks
    assert "deleted" in ctl.do("delete_track")
    assert tid not in ctl.project.tracks and ctl.selected is None


def test_logger_sends_one_track_and_empties_frames_it_left(ctl):
    """send_track writes only the track's entities; a shrunk track's old frames get empty rows."""
    pytest.importorskip("rerun")
    from annotate.app.session import track_columns
    from s2p_review.annotation_log import AnnotationLogger

    sent = []

    class Rec:
        def send_columns(self, ent, indexes, columns):
            sent.append((ent, len(indexes[0].as_arrow_array())))

        def log(self, *a, **k):
            pass

        def flush(self):
            pass

    ctl.do("new_track")
    tid = ctl.selected
    ctl.project.set_keyframe(tid, 0, 0.0, -10.0, heading=0.0)
    ctl.project.set_keyframe(tid, 2, 2.0, -10.0, heading=0.0)
    log = AnnotationLogger(Rec(), ctl.project.scene, ["c1"])
    log.send_track(track_columns(ctl.project, tid))
    assert {e for e, _ in sent} == {f"world/annotation/t{tid}", f"world/annotation/t{tid}/trail",
                                    f"world/cameras/c1/annotation/t{tid}"}
    assert all(n == 3 for _, n in sent)
    sent.clear()
    ctl.project.delete_keyframe(tid, 2)
    log.send_track(track_columns(ctl.project, tid))
    assert all(n == 3 for _, n in sent)  # frames 0..2: frames 1, 2 emptied
    assert log.sent[tid] == (0, 0)


def test_run_of_another_scene_is_refused(scene_dir, tmp_path):
    from annotate.app.serve import check_scene
    from seg2pose.core.errors import S2PError

    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"scene_fingerprint": "0123456789abcdef"}')
    (run / "poses.csv").write_text("frame,track_id,class,x,y,z,heading\n0,1,car,0,0,0,0\n")
    with pytest.raises(S2PError, match="another scene"):
        check_scene(scene_dir, run, None)
    with pytest.raises(S2PError, match="unknown cameras"):
        check_scene(scene_dir, None, ["nope"])


def test_session_wiring_without_a_browser(scene_dir):
    """The page's wiring: viewer events and panel messages reach the controller, edits reach
    the viewer's data stream, the panel's HTML follows."""
    import shutil

    pytest.importorskip("rerun_notebook", reason="rerun-notebook is not installed (pip install -e '.[app]')")
    from rerun.notebook import EntitySelectionItem, SelectionChangeEvent, TimeUpdateEvent

    from annotate.app.session import Session

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    s = Session(scene_dir, cameras=["c1"])
    try:
        sent = []
        s.viewer._viewer.send_rrd = lambda data: sent.append(len(data))
        assert not s._logged  # nothing goes to the viewer before the page says it shows it
        s._on_panel_msg(None, {"hello": "tab", "renderer": "ANGLE (NVIDIA GeForce)"}, [])
        assert s._logged and s.ctl.viewer_visible
        ev = dict(application_id="s2p-annotate", recording_id="r", segment_id=None)
        moves = []
        s.viewer.set_time_ctrl = lambda **k: moves.append(k["sequence"])
        s._on_viewer_event(TimeUpdateEvent(time=10.0, **ev))  # streaming: the viewer follows data
        assert s.ctl.frame == 0 and moves == [0] and s.ctl.viewer_state != "ready"
        s._on_viewer_event(TimeUpdateEvent(time=0.0, **ev))   # it shows the page's frame: in sync
        assert s.ctl.viewer_state == "ready"
        s._on_viewer_event(TimeUpdateEvent(time=2.0, **ev))   # from now on the viewer leads
        assert s.ctl.frame == 2 and 'data-testid="frame-number">2<' in s.panel.html
        s._on_panel_msg(None, {"action": "new_track"}, [])
        tid = s.ctl.selected
        assert f'data-track="{tid}"' in s.panel.html
        from annotate.place import pixel_to_ground

        scene = s.ctl.project.scene
        xy = pixel_to_ground(scene.cameras["c1"], scene.ground, (640.0, 420.0))
        s.ctl.click_mode = "ground"
        sent.clear()
        s._on_viewer_event(SelectionChangeEvent(items=[EntitySelectionItem(
            entity_path="/world/cameras/c1/masks", view_name="camera c1", position=[640.0, 420.0, None])], **ev))
        k = s.ctl.project.track(tid).keyframes[2]
        assert np.hypot(k.x - xy[0], k.y - xy[1]) < 1e-6
        assert sent, "the new keyframe's track was not sent to the viewer"
        # a click on the 3D view's ground places the keyframe at that world point; one above
        # the ground (a box) is ignored with the reason
        g = float(scene.ground.height(np.array([[1.0, 2.0]]))[0])
        s._on_viewer_event(SelectionChangeEvent(items=[EntitySelectionItem(
            entity_path="/world/ground/mesh", view_name="world", position=[1.0, 2.0, g])], **ev))
        k = s.ctl.project.track(tid).keyframes[2]
        assert (k.x, k.y) == (1.0, 2.0), s.ctl.message
        s._on_viewer_event(SelectionChangeEvent(items=[EntitySelectionItem(
            entity_path="/world/annotation/t1", view_name="world", position=[1.0, 2.0, g + 1])], **ev))
        assert "click ignored" in s.ctl.message and "from the ground" in s.ctl.message
        # a repeated click: the viewer reports no selection change, the page reports the canvas
        # click at the same page point as the last one that selected: it is that click again
        s.ctl.click_mode = "ground"
        s._on_panel_msg(None, {"canvas_click": [400, 300]}, [])     # (after the world click)
        s._on_viewer_event(SelectionChangeEvent(items=[EntitySelectionItem(
            entity_path="/world/cameras/c1/masks", view_name="camera c1",
            position=[640.0, 420.0, None])], **ev))
        s._on_panel_msg(None, {"canvas_click": [500, 320]}, [])     # it selected: remembered
        s.ctl.do("nudge:0.5:0")
        moved = s.ctl.project.track(tid).keyframes[2].x
        s._on_panel_msg(None, {"canvas_click": [501, 320]}, [])     # same point, no selection
        assert s.ctl.project.track(tid).keyframes[2].x == pytest.approx(moved - 0.5)
        s.ctl.do("nudge:0.5:0")
        s._on_panel_msg(None, {"canvas_click": [900, 700]}, [])     # elsewhere (time panel): nothing
        assert s.ctl.project.track(tid).keyframes[2].x == pytest.approx(moved)
        s._on_panel_msg(None, {"canvas_click": [501, 320], "frame": 7}, [])  # made at another frame
        assert s.ctl.project.track(tid).keyframes[2].x == pytest.approx(moved)
        assert "made at frame 7" in s.ctl.message
    finally:
        s.ctl.close()


def test_a_reloaded_tab_keeps_the_edit_lock_another_tab_does_not(scene_dir):
    import shutil

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    first = Controller.open(scene_dir, cameras=["c1"])
    first.hello("tab-A")
    other = Controller.open(scene_dir, cameras=["c1"])   # a second tab: read-only
    other.hello("tab-B")
    assert other.read_only and not first.read_only
    reloaded = Controller.open(scene_dir, cameras=["c1"])  # tab A reloaded: opens read-only...
    assert reloaded.read_only
    reloaded.hello("tab-A")                                # ...and takes its lock back at once
    try:
        assert not reloaded.read_only and reloaded.read_only_reason is None
        reloaded.do("new_track")
        assert reloaded.selected in reloaded.project.tracks
    finally:
        for c in (reloaded, other, first):
            c.close()


def test_large_camera_picture_its_clicks_and_the_small_ones(scene_dir):
    """The large camera's picture follows the frame; a click on it places a keyframe at that
    pixel unless the picture was of another frame; under software rendering the viewer is off
    and the other cameras come as small pictures, a click on one shows it large; Shift+V
    brings the viewer back (and the small pictures go)."""
    import shutil

    pytest.importorskip("rerun_notebook", reason="rerun-notebook is not installed (pip install -e '.[app]')")
    from annotate.app.session import Session

    shutil.rmtree(scene_dir / "annotations", ignore_errors=True)
    s = Session(scene_dir, cameras=["c0", "c1"])
    try:
        s._on_panel_msg(None, {"hello": "tab", "renderer": "ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device))"}, [])
        assert s.ctl.software_rendering and not s.ctl.viewer_visible and s.panel.hide_viewer
        v = s.frame_view.view
        assert (v["camera"], v["frame"]) == ("c0", 0) and [t["camera"] for t in v["thumbs"]] == ["c1"]
        s._on_frame_msg(None, {"large": "c1"}, [])
        v = s.frame_view.view
        assert v["camera"] == "c1" and [t["camera"] for t in v["thumbs"]] == ["c0"]
        s._on_panel_msg(None, {"action": "next_frame"}, [])
        assert s.frame_view.view["frame"] == 1
        s._on_panel_msg(None, {"action": "new_track"}, [])
        tid = s.ctl.selected
        s.ctl.click_mode = "ground"
        s._on_frame_msg(None, {"click": [640.0, 420.0], "camera": "c1", "frame": 0}, [])  # an old picture
        assert "click ignored" in s.ctl.message and not s.ctl.project.track(tid).keyframes
        s._on_frame_msg(None, {"click": [640.0, 420.0], "camera": "c1", "frame": 1}, [])
        assert _pixel(s.ctl, (s.ctl.project.track(tid).keyframes[1].x,
                              s.ctl.project.track(tid).keyframes[1].y), 0.0) == pytest.approx([640.0, 420.0], abs=1e-3)
        s._on_frame_msg(None, {"click": [640.0, 420.0], "camera": "c1", "frame": 1}, [])  # again: an edit
        assert s.ctl.project.seq == 3  # new track, two placements
        s._on_panel_msg(None, {"action": "toggle_viewer"}, [])
        assert s.ctl.viewer_visible and not s.panel.hide_viewer and s.frame_view.view["thumbs"] == []
    finally:
        s.ctl.close()
