"""The README as a newcomer uses it: every shell command in its ```sh blocks runs as written,
in a fresh folder, on a tiny scene, with the installed ``s2p`` -- except the few lines listed
in ``SKIP`` and ``INSTEAD`` with the reason. The README stays short (<= 250 lines)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
MAX_LINES = 250
# lines not run, by their start: why
SKIP = {
    "make demo": "the set-up itself (installs, then the demo: minutes)",
    "make test": "the set-up itself (the whole suite, this test included)",
}
# lines run differently, by their start: why (the replacement is in ``_command``)
INSTEAD = {
    "s2p synth ": "a tiny scene: --frames 4 (4 frames per split) --workers 1",
    "s2p train ": "training takes CPU minutes: the shipped demo models (the same device) are put "
                  "where s2p train writes its models, SCENE/models",
}


def shell_lines(text: str) -> list[str]:
    """The commands of the ```sh blocks, comments dropped, continuation lines joined."""
    out, block, pending = [], False, ""
    for line in text.splitlines():
        if line.startswith("```"):
            block = line.strip() == "```sh"
            continue
        if not block:
            continue
        cmd = pending + re.sub(r"\s+#.*$", "", line).strip()
        if cmd.endswith("\\"):
            pending = cmd[:-1].rstrip() + " "
            continue
        pending = ""
        if cmd and not cmd.startswith("#"):
            out.append(cmd)
    return out


def _command(line: str, cwd: Path) -> list[str] | None:
    """argv to run for a README line (None: done here instead)."""
    argv = shlex.split(line)
    if line.startswith("s2p synth "):
        return argv + ["--frames", "4", "--workers", "1", "--no-progress"]
    if line.startswith("s2p train "):
        from seg2pose.training.demo_models import SHIPPED

        shutil.copytree(SHIPPED / "bench-seed7", cwd / argv[2] / "models")
        return None
    return argv


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines"


def test_shell_lines_are_parsed():
    text = "x\n```sh\na --b  # c\nd \\\n  e\n# f\n```\n```python\ng\n```\n"
    assert shell_lines(text) == ["a --b", "d e"]


def test_readme_commands_run_as_written(tmp_path):
    lines = shell_lines(README.read_text(encoding="utf-8"))
    assert len(lines) >= 10
    s2p_bin = Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{s2p_bin}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("PYTHONPATH", None)
    ran = []
    for line in lines:
        if any(line.startswith(s) for s in SKIP):
            continue
        assert line.startswith("s2p "), f"README line neither run nor listed in SKIP: {line}"
        argv = _command(line, tmp_path)
        if argv is None:
            continue
        r = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"{line}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
        ran.append(line)
    assert len(ran) >= 8
    assert set(SKIP) | set(INSTEAD) == {k for k in (*SKIP, *INSTEAD) if any(x.startswith(k) for x in lines)}, \
        "a SKIP or INSTEAD entry matches no README line: remove it"
