"""Fuzzing of the annotation journal's replay (hypothesis): a journal with one record mutated (a
field replaced by a hostile value, removed or swapped), a line dropped, repeated or swapped,
or the file cut short. Opening the project either refuses in one line naming the segment, or
replays to tracks whose every row a poses.csv can hold: the project's ground truth exports,
and the export reads back (the journal's operations and poses.csv have one schema each, and
a replayed operation is checked by the same one as a new edit)."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import pytest
from fuzz_fixtures import FUZZ, folder, mutate_json, mutate_text, only_s2p_errors
from hypothesis import given
from hypothesis import strategies as st

from seg2pose.io.poses import read_poses


@pytest.fixture(scope="module")
def journalled(tmp_path_factory) -> Path:
    """A scene whose journal holds tracks, keyframes, spans, a resize, an undo and a redo."""
    from review_fixtures import make_scene

    from annotate import Project

    scene = make_scene(tmp_path_factory.mktemp("journal") / "scene", n_frames=12)
    with Project.open(scene) as p:
        a = p.create_track("car").track
        p.set_keyframe(a, 1, 1.0, 2.0, heading=0.5)
        p.set_keyframe(a, 6, 3.0, 2.5, heading=0.25)
        b = p.create_track("pedestrian").track
        p.set_keyframe(b, 2, -1.0, 0.5, heading=1.0)
        p.set_keyframe(b, 9, -0.5, 1.5)
        p.mark(a, 3, 4, "occluded")
        p.set_size(b, (0.7, 0.6, 1.8))
        p.undo()
        p.redo()
    return scene.root


def _segment(root: Path) -> Path:
    from annotate import journal as J

    segs, _ = J.list_files(root / "annotations")
    return segs[max(segs)]


def _replays_to_readable_ground_truth(root: Path, d: Path) -> None:
    from annotate import Project
    from annotate.export import export_gt

    def open_and_export():
        with Project.open(root) as p:  # writable: a torn tail is moved aside
            if len(p.poses()):
                export_gt(p, d / "gt.csv")
            return True

    if only_s2p_errors(open_and_export) and (d / "gt.csv").exists():
        read_poses(d / "gt.csv")


@FUZZ
@given(data=st.data())
def test_journal_record_mutated(journalled, data):
    with folder() as d:
        root = d / "scene"
        shutil.copytree(journalled, root)
        seg = _segment(root)
        lines = seg.read_text().splitlines()
        i = data.draw(st.integers(1, len(lines) - 1))  # a record after the header
        lines[i] = mutate_json(data, json.loads(lines[i]))
        seg.write_text("\n".join(lines) + "\n")
        _replays_to_readable_ground_truth(root, d)


@FUZZ
@given(data=st.data())
def test_journal_lines_damaged(journalled, data):
    with folder() as d:
        root = d / "scene"
        shutil.copytree(journalled, root)
        seg = _segment(root)
        seg.write_text(mutate_text(data, seg.read_text(), None))
        _replays_to_readable_ground_truth(root, d)


@FUZZ
@given(st.sampled_from(["frame", "x", "heading"]),
       st.sampled_from([1.5, -3, 10**15, 2**63, 1e300, -1e7, "1", None, True, []]))
def test_journal_keyframe_values(journalled, what, value):
    """A keyframe row's frame, x or heading replaced: refused in one line, or exported."""
    with tempfile.TemporaryDirectory() as t:
        d = Path(t)
        root = d / "scene"
        shutil.copytree(journalled, root)
        seg = _segment(root)
        lines = seg.read_text().splitlines()
        for i, ln in enumerate(lines):
            rec = json.loads(ln)
            if rec.get("kind") == "edit" and rec["ops"][0]["op"] == "set_keyframes":
                rec["ops"][0]["set"][0][{"frame": 0, "x": 1, "heading": 3}[what]] = value
                lines[i] = json.dumps(rec)
                break
        seg.write_text("\n".join(lines) + "\n")
        _replays_to_readable_ground_truth(root, d)
