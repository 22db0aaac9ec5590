"""Every module of the three packages, and every test and bench file, is readable in one
sitting: at most ``MAX_LINES`` lines (a longer one is split by concern, as
``annotate/project.py`` into ``history.py``, ``cli/method.py`` into ``cli/evaluation.py`` and
``tests/system/test_writers.py`` into it and ``test_writer_sets.py``)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("seg2pose", "s2p_review", "annotate")
CHECKED = PACKAGES + ("tests", "benches")
MAX_LINES = 450


def long_modules(root: Path = ROOT, limit: int = MAX_LINES) -> list[str]:
    """'path: N lines' of each module of the packages, tests and benches under ``root`` longer
    than ``limit``."""
    out = []
    for pkg in CHECKED:
        for p in sorted((root / pkg).rglob("*.py")):
            n = len(p.read_text(encoding="utf-8").splitlines())
            if n > limit:
                out.append(f"{p.relative_to(root)}: {n} lines")
    return out


def test_every_module_is_at_most_450_lines():
    for folder, least in (("seg2pose", 50), ("tests", 50), ("benches", 10)):
        assert len(list((ROOT / folder).rglob("*.py"))) > least, folder
    assert long_modules() == []


def test_the_check_sees_a_long_module(tmp_path):
    """Not vacuous: a planted module, test or bench of 451 lines is reported, one of 450 is
    not."""
    for folder in ("annotate", "tests/system", "benches"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "ok.py").write_text("x = 1\n" * 450)
        (tmp_path / folder / "long.py").write_text("x = 1\n" * 451)
    assert long_modules(tmp_path) == [f"{Path(f) / 'long.py'}: 451 lines"
                                      for f in ("annotate", "tests/system", "benches")]
