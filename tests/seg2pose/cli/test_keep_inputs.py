"""No output replaces what the command reads (seg2pose/cli/keep_inputs.py): before the check,
``s2p run SCENE -o SCENE --force`` replaced the whole scene folder by a run folder, and
``s2p conflicts RUN -o RUN/poses.csv --force`` the run's poses by the conflicts table. Each
case is refused in one line naming the output, and every file is as it was; outputs beside the
inputs (SCENE/out/..., a new file in a run folder) still work."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest
from hostile_fixtures import write_scene

S2P = str(Path(sys.executable).with_name("s2p"))


def _s2p(*argv, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([S2P, *map(str, argv)], capture_output=True, text=True, timeout=300, cwd=cwd)


def _digest(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("keep")
    scene = write_scene(root / "scene", frames=8, users=2).root
    r = _s2p("run", scene, "-o", scene / "out" / "base", "--baseline")
    assert r.returncode == 0, r.stderr
    return root, scene, scene / "out" / "base"


CASES = [  # (argv with {S} scene, {R} run; what the one line says)
    ("run {S} --baseline -o {S} --force", "is this command's input"),
    ("run {S} --baseline -o {S}/ --force", "is this command's input"),
    ("run {S} --baseline -o {S}/masks --force", "is the masks of the scene"),
    ("run {S} --baseline -o {S}/gt --force", "is the gt of the scene"),
    ("run {S} --baseline -o {S}/scene.json --force", "is the scene.json of the scene"),
    ("run {S} --baseline -o {S}/.. --force", "holds this command's input"),
    ("conflicts {R} -o {R}/poses.csv --force", "is the poses.csv of the run"),
    ("conflicts {R} -o {R} --force", "is this command's input"),
    ("conflicts {R}/poses.csv -o {R}/poses.csv --force", "is this command's input"),
    ("conflicts {R} -o {S}/c.csv --map {R}/views.csv --force", "is the views.csv of the run"),
    ("export {S} --run {R} -o {R}/run.json --force", "is the run.json of the run"),
    ("review {S} --run {R} -o {S}/ground_points.csv --force", "is the ground_points.csv of the scene"),
    ("convert-masks {S}/masks/c0.txt -o {S}/masks/c0.txt --format coco --force", "is this command's input"),
    ("annotate export {S} -o {S}/gt --force", "is the gt of the scene"),
    ("calibrate-errors {S} --run {R} -o {R}/poses.csv --force", "is the poses.csv of the run"),
]


@pytest.mark.parametrize("argv,said", CASES, ids=[c[0].split(" -o ")[0] + " -o " + c[0].split(" -o ")[1].split()[0]
                                                  for c in CASES])
def test_an_output_never_replaces_an_input(site, argv, said):
    root, scene, run = site
    before = _digest(root)
    r = _s2p(*argv.format(S=scene, R=run).split())
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and said in lines[0], r.stderr
    assert "choose another output" in lines[0]
    assert _digest(root) == before  # nothing lost, nothing written


def test_the_same_path_through_another_spelling_is_caught(site):
    root, scene, run = site
    r = _s2p("conflicts", Path("scene") / "out" / "base", "-o", Path("scene") / "out" / ".." / "out" / "base" /
             "poses.csv", "--force", cwd=root)
    assert r.returncode == 2 and "is the poses.csv of the run" in r.stderr, r.stderr


def test_outputs_beside_the_inputs_still_work(site, tmp_path):
    root, scene, run = site
    r = _s2p("conflicts", run, "-o", run / "conflicts.csv")  # a new file in the run folder
    assert r.returncode == 0, r.stderr
    r = _s2p("run", scene, "--baseline", "-o", scene / "out" / "base2")
    assert r.returncode == 0, r.stderr
    (run / "conflicts.csv").unlink()
