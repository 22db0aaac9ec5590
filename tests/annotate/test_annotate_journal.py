"""Crash safety of the annotation journal: kills, torn lines, full disk, locks, snapshots,
scene fingerprints, read-only viewers."""

import errno
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import pytest
from annotate_fixtures import digest, random_edit, state
from review_fixtures import make_scene

from annotate import EditError, JournalError, LockedError, NotSavedError, Project
from annotate import journal as J


@pytest.fixture
def scene(tmp_path):
    return make_scene(tmp_path / "scene", n_frames=30)


def segment(scene):
    segs, _ = J.list_files(scene.root / "annotations")
    return segs[max(segs)]


def acked_state(scene, seq: int) -> str:
    """Digest of the project as it was after record ``seq``: a copy of the scene whose journal
    stops there."""
    copy = scene.root.parent / "acked"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(scene.root, copy)
    path = segment(scene)
    keep = [line for line in path.read_text().splitlines(keepends=True)
            if json.loads(line).get("seq", 0) <= seq]
    (copy / "annotations" / path.name).write_text("".join(keep))
    with Project.open(copy, read_only=True) as p:
        assert p.seq == seq
        return digest(p)


def _writer(root: str, seed: int, ack_fd: int) -> None:
    """Child process: edit forever, reporting 'seq digest' after every acknowledged edit."""
    try:
        p = Project.open(root)
        os.write(ack_fd, f"{p.seq} {digest(p)}\n".encode())
        rng = random.Random(seed)
        while True:
            random_edit(p, rng)
            os.write(ack_fd, f"{p.seq} {digest(p)}\n".encode())
    finally:
        os._exit(0)


def test_sigkill_at_random_moments_loses_no_acknowledged_edit(scene):
    rng = random.Random(1234)
    kills = 0
    for session in range(20):
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child
            os.close(r)
            _writer(str(scene.root), session, w)
        os.close(w)
        acks, buf = {}, b""

        def read_acks():
            nonlocal buf
            chunk = os.read(r, 4096)
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for line in lines:
                s, d = line.decode().split()
                acks[int(s)] = d
            return bool(chunk)

        want = rng.randrange(1, 12)
        deadline = time.monotonic() + 10
        while len(acks) < want and time.monotonic() < deadline and read_acks():
            pass
        time.sleep(rng.uniform(0, 0.004))  # land the kill anywhere, mid-write included
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        kills += 1
        while read_acks():  # acknowledgements sent before the kill count too
            pass
        os.close(r)
        last = max(acks)
        with Project.open(scene.root, read_only=True) as p:
            # every acknowledged edit is there; at most the one being written is extra
            assert last <= p.seq <= last + 1
            assert digest(p) == acks[last] if p.seq == last else acked_state(scene, last) == acks[last]
    assert kills == 20
    # a writer takes over the dead one's lock, and replay equals a clean second replay
    with Project.open(scene.root) as p:
        assert any("took over the lock" in n for n in p.notes)
        live = digest(p)
    with Project.open(scene.root, read_only=True) as q:
        assert digest(q) == live and q.seq > 20


def test_lock_refuses_a_second_writer_naming_the_holder(scene):
    with Project.open(scene) as p:
        p.create_track("car")
        with pytest.raises(LockedError, match=rf"pid {os.getpid()} on .+ since 20\d\d-"):
            Project.open(scene)
        with Project.open(scene, read_only=True) as viewer:  # a second tab may watch
            assert set(viewer.tracks) == {1}
            with pytest.raises(EditError, match="read-only"):
                viewer.create_track("car")
            p.create_track("pedestrian")
            ch = viewer.refresh()
            assert ch.created == {2} and set(viewer.tracks) == {1, 2}
    with Project.open(scene) as p:  # released on close
        assert not p.notes


def test_stale_lock_of_a_dead_process_is_taken_over_with_a_note(scene):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    folder = scene.root / "annotations"
    folder.mkdir()
    (folder / "lock").write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename,
                                             "since": "2026-01-01T00:00:00+00:00"}))
    with Project.open(scene) as p:
        assert p.notes == [f"took over the lock of pid {dead.pid} on {os.uname().nodename} "
                           "(since 2026-01-01T00:00:00+00:00), which no longer runs"]
    lines = segment(scene).read_text().splitlines()
    assert json.loads(lines[-1])["kind"] == "note"


def test_torn_last_line_is_reported_and_skipped(scene):
    with Project.open(scene) as p:
        p.create_track("car")
        p.set_keyframe(1, 3, 1.0, 2.0, 0.5)
        before = state(p)
    path = segment(scene)
    with open(path, "ab") as f:
        f.write(b'{"seq":3,"kind":"edit","name":"set_keyframe","ops":[{"op":"set_ke')
    with Project.open(scene, read_only=True) as v:  # a viewer skips it and touches nothing
        assert state(v) == before and "the last line is torn" in v.notes[0]
    with Project.open(scene) as p:
        assert state(p) == before and p.seq == 2
        assert "journal-000000.jsonl:4: the last line is torn" in p.notes[0]
        assert list((scene.root / "annotations").glob("torn-*.jsonl"))
        p.set_keyframe(1, 4, 2.0, 2.0, 0.5)  # appends cleanly after the cut
    with Project.open(scene) as p:
        assert not p.notes and p.track(1).frames == [3, 4]


def test_damage_before_the_last_line_is_an_error_naming_the_line(scene):
    with Project.open(scene) as p:
        p.create_track("car")
        p.create_track("car")
    path = segment(scene)
    lines = path.read_bytes().split(b"\n")
    lines[1] = b"garbage"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(JournalError, match=r"journal-000000.jsonl:2: not a JSON object"):
        Project.open(scene, read_only=True)


def test_full_disk_reports_the_edit_not_saved_and_keeps_earlier_ones(scene, monkeypatch):
    real_write = os.write
    with Project.open(scene) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, 1.0, 1.0, 0.0)
        before, size = state(p), segment(scene).stat().st_size
        fd = p._segment.fd

        def full(f, data):
            if f == fd:  # half the line reaches the disk, then it is full
                real_write(f, data[: len(data) // 2])
                raise OSError(errno.ENOSPC, "No space left on device")
            return real_write(f, data)

        monkeypatch.setattr(os, "write", full)
        with pytest.raises(NotSavedError, match="edit not saved: the disk is full"):
            p.set_keyframe(1, 5, 2.0, 1.0, 0.0)
        assert state(p) == before and p.seq == 2 and not p.can_redo
        assert segment(scene).stat().st_size == size  # the half line was cut off again
        monkeypatch.setattr(os, "write", real_write)
        p.set_keyframe(1, 6, 3.0, 1.0, 0.0)
    with Project.open(scene) as p:
        assert p.track(1).frames == [0, 6] and not p.notes


def test_journal_of_another_scene_is_refused(scene, tmp_path):
    with Project.open(scene) as p:
        p.create_track("car")
    pts = scene.ground_points.copy()
    pts[0, 2] += 0.5  # another ground survey: another scene
    scene.ground_points = pts
    scene.save()
    with pytest.raises(JournalError, match="belongs to scene 'tiny' .* but this scene's is"):
        Project.open(scene.root)


def test_snapshots_compact_without_losing_undo_history(scene):
    rng = random.Random(5)
    with Project.open(scene, snapshot_every=10) as p:
        states = [state(p)]
        for _ in range(35):
            random_edit(p, rng, allow_undo=False)
            states.append(state(p))
        live, hist = digest(p), p.history()
    files = sorted(f.name for f in (scene.root / "annotations").iterdir())
    assert files == ["journal-000030.jsonl", "lock", "snapshot-000030.json"]
    with Project.open(scene, snapshot_every=10) as p:
        assert digest(p) == live and p.history() == hist and len(hist) == 35
        for k in range(35):  # undo past the snapshot, back to the empty project
            p.undo()
            assert state(p) == states[-2 - k]
        assert not p.tracks
    with Project.open(scene, read_only=True) as p:
        assert not p.tracks and p.can_redo


def test_a_record_that_cannot_be_replayed_names_file_and_line(scene):
    with Project.open(scene) as p:
        p.create_track("car")
    path = segment(scene)
    with open(path, "a") as f:  # an edit of a track that never existed, then a complete line
        f.write('{"seq":2,"kind":"edit","name":"x","ops":[{"op":"set_keyframes","id":9,'
                '"set":[[1,0.0,0.0,0.0,[]]]}],"t":"now"}\n')
    with pytest.raises(JournalError, match=r"journal-000000.jsonl:3: cannot replay this record: "
                                           r"no track 9"):
        Project.open(scene, read_only=True)


def test_a_complete_last_record_without_its_newline_counts_as_torn(scene):
    with Project.open(scene) as p:
        p.create_track("car")
    path = segment(scene)
    with open(path, "a") as f:
        f.write('{"seq":2,"kind":"note","text":"cut before its newline"}')
    with Project.open(scene) as p:
        assert p.seq == 1 and "journal-000000.jsonl:3: the last line is torn" in p.notes[0]


def test_a_snapshot_that_cannot_be_written_is_a_note_and_the_edit_is_saved(scene, monkeypatch):
    """Issue 24: a full disk when a snapshot is due. The edit was journalled, so it is
    reported saved; subscribers hear every edit; the snapshot is tried again later and the
    reopened project holds every edit."""
    from seg2pose.core.errors import S2PError

    real = J.atomic_write_text
    full = {"on": True}

    def write(path, text):
        if full["on"] and "snapshot-" in str(path):
            raise S2PError(f"cannot write {path}: the disk is full")
        return real(path, text)

    monkeypatch.setattr(J, "atomic_write_text", write)
    heard = []
    rng = random.Random(7)
    with Project.open(scene, snapshot_every=5) as p:
        p.subscribe(heard.append)
        for k in range(30):
            random_edit(p, rng, allow_undo=False)
            if k == 20:
                full["on"] = False  # space again: the next retry writes the snapshot
        assert len(heard) == 30 and p.seq == 30
        assert any("snapshot" in n and "saved in the journal" in n for n in p.notes)
        live = digest(p)
    names = sorted(f.name for f in (scene.root / "annotations").iterdir())
    assert any(n.startswith("snapshot-") for n in names)
    with Project.open(scene) as p:
        assert digest(p) == live and p.seq == 30


def test_a_snapshot_whose_new_segment_fails_is_taken_back(scene, monkeypatch):
    """The snapshot is written but its journal segment cannot be: the snapshot is removed
    (it would hide the records still appended to the old segment) and the edit stays saved."""
    real = J.new_segment
    calls = {"n": 0}

    def failing(folder, after, header):
        if after > 0 and calls["n"] == 0:
            calls["n"] += 1
            raise NotSavedError(f"{folder}: edit not saved: the disk is full")
        return real(folder, after, header)

    monkeypatch.setattr(J, "new_segment", failing)
    rng = random.Random(3)
    with Project.open(scene, snapshot_every=4) as p:
        for _ in range(12):
            random_edit(p, rng, allow_undo=False)
        live = digest(p)
    with Project.open(scene) as p:
        assert digest(p) == live and p.seq == 12
