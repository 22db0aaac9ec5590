"""The package as a user installs it: a wheel built from the source (no network: setuptools of
the project's environment, ``--no-build-isolation``), installed ``--no-deps`` into a fresh
virtual environment that sees the project's dependencies through a ``.pth`` line (so torch and
the rest are not installed twice), then used from a folder outside the repository:
``s2p --help``, ``s2p synth`` on a tiny scene and ``s2p run --baseline`` on it. Also: every
module of the three packages and the shipped demo models are in the wheel, and the installed
models are the repository's, byte for byte."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("seg2pose", "s2p_review", "annotate")
DEMO_MODELS = Path("seg2pose/data/demo_models")


def _run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 120) -> str:
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}"
    return r.stdout + r.stderr


def _source_files() -> list[str]:
    """Every file the wheel must hold: the packages' modules and the demo models' files."""
    out = []
    for pkg in PACKAGES:
        out += [p.relative_to(ROOT).as_posix() for p in (ROOT / pkg).rglob("*.py")
                if "__pycache__" not in p.parts]
    out += [p.relative_to(ROOT).as_posix() for p in (ROOT / DEMO_MODELS).rglob("*")
            if p.is_file() and p.suffix in (".json", ".safetensors")]
    return sorted(out)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict[str, str], Path]:
    """(the fresh environment's bin folder, the environment to run it in, the wheel)."""
    tmp = tmp_path_factory.mktemp("wheel")
    # a copy of the source, so the build's own build/ folder cannot hold stale modules
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, src / pkg, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PIP_NO_INDEX"] = "1"  # nothing downloaded
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
          "--no-cache-dir", "-w", str(tmp / "dist"), str(src)], cwd=tmp, env=env)
    (wheel,) = (tmp / "dist").glob("seg2pose-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp, env=env)
    py = venv / "bin" / "python"
    purelib = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                        cwd=tmp, env=env).strip())
    # the project's dependencies, after the fresh environment's own site-packages
    (purelib / "s2p_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
         cwd=tmp, env=env)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return venv / "bin", env, wheel


def test_the_wheel_holds_every_module_and_the_demo_models(installed):
    _, _, wheel = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    want = _source_files()
    assert len(want) > 150 and any(n.endswith(".safetensors") for n in want)
    assert [n for n in want if n not in names] == []
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "s2p = seg2pose.cli:main" in entry


def test_installed_s2p_runs_outside_the_repository(installed, tmp_path):
    bin_dir, env, _ = installed
    s2p, py = str(bin_dir / "s2p"), str(bin_dir / "python")
    where = _run([py, "-c", "import seg2pose, s2p_review, annotate; "
                            "print(seg2pose.__file__, s2p_review.__file__, annotate.__file__)"],
                 cwd=tmp_path, env=env)
    for f in where.split():
        assert Path(f).is_relative_to(bin_dir.parent), f"imported from {f}, not the installed wheel"
    out = _run([s2p, "--help"], cwd=tmp_path, env=env)
    for command in ("synth", "run", "eval", "review", "annotate"):
        assert command in out
    _run([s2p, "synth", "-o", "scene", "--frames", "4", "--no-progress", "--workers", "1"],
         cwd=tmp_path, env=env)
    assert (tmp_path / "scene" / "scene.json").is_file()
    out = _run([s2p, "run", "scene", "-o", "scene/out", "--baseline"], cwd=tmp_path, env=env)
    assert "baseline run of" in out
    rows = (tmp_path / "scene" / "out" / "poses.csv").read_text().splitlines()
    assert rows[0].startswith("frame,track_id,class,x,y,z,heading") and len(rows) > 10
    # the shipped models, found where the installed package looks for them, fit the scene
    shipped = _run([py, "-c", "from seg2pose.training.demo_models import SHIPPED, fit_problem; "
                              "from seg2pose.io.scene import load_scene; "
                              "print(SHIPPED); print(fit_problem(load_scene('scene')))"],
                   cwd=tmp_path, env=env).split()
    assert Path(shipped[0]).is_relative_to(bin_dir.parent) and shipped[1] == "None"
    for f in (ROOT / DEMO_MODELS).rglob("*.safetensors"):
        there = Path(shipped[0]) / f.relative_to(ROOT / DEMO_MODELS)
        assert hashlib.sha256(there.read_bytes()).digest() == hashlib.sha256(f.read_bytes()).digest()
