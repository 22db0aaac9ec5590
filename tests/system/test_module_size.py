"""Every module of the three packages is readable in one sitting: at most ``MAX_LINES`` lines
(a longer one is split by concern, as ``annotate/project.py`` into ``history.py`` and
``cli/method.py`` into ``cli/evaluation.py``)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("seg2pose", "s2p_review", "annotate")
MAX_LINES = 450


def long_modules(root: Path = ROOT, limit: int = MAX_LINES) -> list[str]:
    """'path: N lines' of each module of the packages under ``root`` longer than ``limit``."""
    out = []
    for pkg in PACKAGES:
        for p in sorted((root / pkg).rglob("*.py")):
            n = len(p.read_text(encoding="utf-8").splitlines())
            if n > limit:
                out.append(f"{p.relative_to(root)}: {n} lines")
    return out


def test_every_module_is_at_most_450_lines():
    assert len(list((ROOT / "seg2pose").rglob("*.py"))) > 50
    assert long_modules() == []


def test_the_check_sees_a_long_module(tmp_path):
    """Not vacuous: a planted module of 451 lines is reported, one of 450 is not."""
    (tmp_path / "annotate").mkdir()
    (tmp_path / "annotate" / "ok.py").write_text("x = 1\n" * 450)
    (tmp_path / "annotate" / "long.py").write_text("x = 1\n" * 451)
    assert long_modules(tmp_path) == [f"{Path('annotate/long.py')}: 451 lines"]
