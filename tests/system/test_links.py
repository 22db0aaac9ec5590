"""Issue 38: ``s2p`` never follows a link inside a scene or output folder. For each writing
command, a link is planted where it writes (the output's folder, a folder of the scene it
writes into, the file it appends to), pointing at a folder outside; the command is refused
with one line naming the link, and nothing outside changes. (Locks, journal segments, commit
records and the masks folder: tests/system/test_write_path.py.)"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hostile_fixtures import link_test_inputs


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A scene, its baseline run and its export, and an annotation project with one track."""
    return link_test_inputs(tmp_path_factory.mktemp("links"))


def _run(monkeypatch, capsys, argv: list) -> tuple[int, str]:
    from seg2pose.cli import main

    monkeypatch.setattr(sys, "argv", ["s2p", *map(str, argv)])
    with pytest.raises(SystemExit) as e:
        main()
    return e.value.code, capsys.readouterr().err


# (name, the folder planted as a link (relative to the work folder), the command's arguments)
CASES = [
    ("export", "out", ["export", "{scene}", "--run", "{run}", "-o", "{w}/out/x.mcap"]),
    ("run", "scene/out", ["run", "{w}/scene", "-o", "{w}/scene/out/run", "--baseline"]),
    ("convert-masks", "out", ["convert-masks", "{scene}/masks/c0.txt", "-o", "{w}/out/m.json",
                              "--format", "coco"]),
    ("review", "out", ["review", "{scene}", "--run", "{run}", "-o", "{w}/out/r.rrd"]),
    ("import-mcap", "imported", ["import-mcap", "{root}/x.mcap", "-o", "{w}/imported", "--force"]),
    ("annotate-export", "ann/export", ["annotate", "export", "{w}/ann", "--force"]),
    ("annotate-gt", "ann/gt", ["annotate", "export", "{w}/ann", "--force", "--gt"]),
]


@pytest.mark.parametrize("name,link,argv", CASES, ids=[c[0] for c in CASES])
def test_a_planted_link_is_refused_and_nothing_outside_changes(made, tmp_path, monkeypatch, capsys,
                                                               name, link, argv):
    import shutil

    root, scene, ann = made
    w = tmp_path / "w"
    w.mkdir()
    shutil.copytree(scene, w / "scene")
    shutil.copytree(ann, w / "ann")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "scene.json").write_text("a colleague's file, not to be touched\n")
    (outside / "x.mcap").write_text("not to be touched\n")
    if (w / link).exists():
        shutil.rmtree(w / link)
    os.symlink(outside, w / link)
    before = _files(outside)
    args = [a.format(scene=w / "scene", run=root / "run", w=w, root=root) for a in argv]
    code, err = _run(monkeypatch, capsys, args)
    assert code == 2, err
    assert err.strip() == err.strip().splitlines()[0] and "Traceback" not in err
    assert f"{w / link} is a symbolic link" in err
    assert _files(outside) == before
