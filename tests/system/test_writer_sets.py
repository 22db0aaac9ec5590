"""Issue 24, the sets: outputs written as one set (``annotate export``, ``import-mcap --force``)
are checked up front and swapped in together, and a set killed at any of its renames is whole
and finished by the next writer of any of its outputs (commit records). The single-output
writers and the importers' limits: tests/system/test_writers.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from scene_fixtures import s2p
from video_fixtures import single_threaded_opencv

from seg2pose.core.errors import S2PError

opencv_one_thread = pytest.fixture(autouse=True)(single_threaded_opencv)


def _boom(*a, **k):
    raise RuntimeError("killed here")



# --- annotate export ----------------------------------------------------------------------------

@pytest.fixture
def annotated(tmp_path):
    from review_fixtures import make_scene

    from annotate import Project

    scene = make_scene(tmp_path / "ann", n_frames=20)
    with Project.open(scene) as p:
        p.create_track("car")
        p.set_keyframe(1, 0, -8.0, -1.5, heading=0.0)
        p.set_keyframe(1, 10, -2.0, -1.5, heading=0.0)
    return scene.root


def _files(root):
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
            and "annotations" not in p.parts}


@pytest.fixture
def exported_then_edited(annotated, monkeypatch, capsys):
    """The annotated scene exported once (``annotate export --force``), then a keyframe added:
    (scene folder, its files but the journal's), so that a second export has something new
    to write over the first one's set."""
    from annotate import Project

    code, _, err = s2p(monkeypatch, capsys, "annotate", "export", annotated, "--force")
    assert code == 0, err
    with Project.open(annotated) as p:
        p.set_keyframe(1, 15, 1.0, -1.5, heading=0.0)
    return annotated, _files(annotated)


def test_annotate_export_refuses_before_writing_anything(exported_then_edited, monkeypatch,
                                                         capsys):
    annotated, before = exported_then_edited
    code, _, err = s2p(monkeypatch, capsys, "annotate", "export", annotated)
    assert code == 2 and err.count("\n") == 1 and "exists; pass --force" in err
    assert _files(annotated) == before  # gt/poses.csv not written beside the old MCAP and CSV


def test_annotate_export_swaps_the_set_in_together(exported_then_edited, monkeypatch):
    import seg2pose.io.tanalyst as T
    from annotate import Project

    annotated, before = exported_then_edited
    monkeypatch.setattr(T, "write_tanalyst", _boom)  # the last output of the set fails
    with pytest.raises(RuntimeError, match="killed here"):
        from seg2pose.cli.annotation import export_set

        with Project.open(annotated, read_only=True) as p:
            export_set(p, annotated / "export", gt=True, mcap=True, tanalyst=True,
                       start="00:00:00.000", force=True)
    assert _files(annotated) == before
    assert [p.name for p in (annotated / "export").iterdir() if p.name.startswith(".")] \
        in ([], [".annotations.mcap.lock"])


def test_a_set_killed_between_two_renames_is_finished_by_the_next_writer(tmp_path):
    """The commit record: the state a kill between the swaps of a set leaves (first output
    swapped, second not) is completed by the next writer of that output."""
    from seg2pose.io.atomic import finish_commits

    a, b = tmp_path / "a.txt", tmp_path / "sub" / "b.txt"
    b.parent.mkdir()
    a.write_text("old a")
    b.write_text("old b")
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True).stdout)
    pa, pb = tmp_path / f".a.txt.partial-{dead}-x", b.parent / f".b.txt.partial-{dead}-y"
    pa.mkdir()
    pb.mkdir()
    (pb / "b.txt").write_text("new b")
    a.write_text("new a")  # a was swapped in; the kill came before b
    (tmp_path / f".a.txt.commit-{dead}.json").write_text(json.dumps(
        [[str(pa / "a.txt"), str(a)], [str(pb / "b.txt"), str(b)]]))
    assert finish_commits(a) == [b]
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert not pb.exists() and not pa.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "sub"]


def _kill_at_swap(n, outs, news):
    """In a forked child: build ``outs`` as one set holding ``news`` and end the process
    (os._exit, as SIGKILL: nothing cleaned up) just before the n-th rename or exchange of its
    commit. Returns the child's exit code (0: the commit had fewer than n renames)."""
    import seg2pose.io.atomic as A
    import seg2pose.io.atomic_set as AS

    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            with A.outputs(outs, force=True) as out:
                for o, text in zip(outs, news):
                    out.file(o).write_text(text)
                calls = [0]

                def counted(f):
                    def g(*a, **k):
                        calls[0] += 1
                        if calls[0] == n:
                            os._exit(9)
                        return f(*a, **k)
                    return g
                os.replace, os.rename = counted(os.replace), counted(os.rename)
                AS.exchange = counted(AS.exchange)
        except BaseException:
            code = 3
        finally:
            os._exit(code)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def test_a_set_killed_at_any_swap_is_whole_and_finished_by_a_writer_of_any_output(tmp_path):
    """Kill a set commit before each of its renames in turn (deterministic, os._exit in a
    forked child): every output is always whole (old or new, never absent), and the next
    writer of *any one* output first finishes the set (a record beside each output's folder),
    so a later writer of another output never rolls a stale build over a newer file."""
    from seg2pose.io.atomic import finish_commits, outputs

    outs = [tmp_path / "gt" / "poses.csv", tmp_path / "export" / "a.mcap",
            tmp_path / "export" / "a.layout.json", tmp_path / "export" / "t.csv"]
    old, new = [f"old {o.name}" for o in outs], [f"new {o.name}" for o in outs]
    n = 0
    while True:
        n += 1
        for o, text in zip(outs, old):
            o.parent.mkdir(exist_ok=True)
            o.write_text(text)
        code = _kill_at_swap(n, outs, new)
        state = [o.read_text() if o.exists() else None for o in outs]
        assert all(s in (a, b) for s, a, b in zip(state, old, new)), (n, state)
        if code == 0:
            assert state == new
            break
        assert code == 9 and n < 50
        # the next writer of the last output alone finishes the set, then writes its own
        with outputs([outs[-1]], force=True) as out:
            assert [o.read_text() for o in outs[:-1]] in (old[:-1], new[:-1]), n
            out.file(outs[-1]).write_text("newer")
        # a later writer of the first output does not bring back the killed set's build
        for o in outs:
            finish_commits(o)
        assert outs[-1].read_text() == "newer", n
        hidden = [p.name for d in (outs[0].parent, outs[1].parent) for p in d.iterdir()
                  if p.name.startswith(".") and not p.name.endswith(".lock")]
        assert [h for h in hidden if ".commit-" in h] == [], (n, hidden)
    assert n > 4  # every rename of the commit was a kill point


def test_annotate_export_mcap_holds_the_sets_gt_not_the_one_it_replaces(annotated, monkeypatch,
                                                                        capsys):
    """The MCAP of an export set shows the set's own ground truth (gt/poses.csv written with
    it), not the scene's earlier gt/poses.csv that the set replaces: two exports of the same
    project are the same bytes, whatever gt/poses.csv held before."""
    mcap = annotated / "export" / "annotations.mcap"
    runs = []
    for _ in range(2):
        code, _, err = s2p(monkeypatch, capsys, "annotate", "export", annotated, "--force")
        assert code == 0, err
        runs.append(mcap.read_bytes())
    assert runs[0] == runs[1]


def test_import_mcap_force_replaces_its_outputs_as_one_set(annotated, tmp_path, monkeypatch,
                                                            capsys):
    """import-mcap --force into an existing scene folder: scene.json, the ground points, the
    run and the journal folder are swapped in as one set (the old journal's files do not stay
    beside the restored ones; a refusal midway leaves every old file); other files stay."""
    import s2p_review.mcap_import as MI

    code, _, err = s2p(monkeypatch, capsys, "annotate", "export", annotated, "--force")
    assert code == 0, err
    mcap, out = annotated / "export" / "annotations.mcap", tmp_path / "restored"
    code, _, err = s2p(monkeypatch, capsys, "import-mcap", mcap, "-o", out)
    assert code == 0, err
    first = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    (out / "annotations" / "segment-999999.jsonl").write_text("an older journal's file\n")
    (out / "keep.txt").write_text("not the import's\n")
    (out / "scene.json").write_text("{}")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def refuse(*a, **k):
        raise S2PError("refused midway")
    monkeypatch.setattr(MI, "restore_scene_files", refuse)
    code, _, err = s2p(monkeypatch, capsys, "import-mcap", mcap, "-o", out, "--force")
    assert code != 0 and "refused midway" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    monkeypatch.undo()
    code, _, err = s2p(monkeypatch, capsys, "import-mcap", mcap, "-o", out, "--force")
    assert code == 0, err
    now = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert now == first | {Path("keep.txt"): b"not the import's\n"}



def test_import_mcap_checks_the_journal_it_restores(annotated, tmp_path, monkeypatch, capsys):
    from annotate import Project
    from annotate.export import journal_files, write_annotation_run
    from s2p_review.annotated_mcap import export_annotated_mcap

    with Project.open(annotated, read_only=True) as p:
        run = write_annotation_run(p, tmp_path / "run")
        journal = journal_files(p)
    name = next(n for n in journal if "journal-" in n)
    lines = journal[name].splitlines(keepends=True)
    journal[name] = lines[0] + b'{"seq": 1, "kind": "edit", "ops": [{"op": "nonsense"}]}\n' \
        + b"".join(lines[2:])
    export_annotated_mcap(Project.open(annotated, read_only=True).scene, run,
                          tmp_path / "bad.mcap", journal)
    code, _, err = s2p(monkeypatch, capsys, "import-mcap", tmp_path / "bad.mcap", "-o",
                       tmp_path / "restored")
    assert code == 2 and err.count("\n") == 1
    assert "bad.mcap" in err and "annotation journal attachment" in err
    assert not (tmp_path / "restored").exists()
