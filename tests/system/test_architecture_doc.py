"""docs/ARCHITECTURE.md matches the tree: every module path it names exists, and it names every
package and every module of seg2pose, s2p_review and annotate."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "ARCHITECTURE.md"
PACKAGES = ("seg2pose", "s2p_review", "annotate")


def named_paths(text: str) -> set[str]:
    """Module paths the page names: `seg2pose/<package>/<module>.py` and the like, and the
    package-relative `io/scene.py` form inside seg2pose's sections."""
    out = set(re.findall(r"\b((?:seg2pose|s2p_review|annotate)(?:/\w+)*/\w+\.py)\b", text))
    for rel in re.findall(r"(?<![\w/])(\w+/\w+\.py)\b", text):
        if rel.split("/")[0] not in PACKAGES + ("tests", "benches", "docs"):
            out.add(f"seg2pose/{rel}")
    return out


def tree_modules() -> set[str]:
    return {p.relative_to(ROOT).as_posix() for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")
            if p.name != "__init__.py" or p.parent.parent == ROOT / "seg2pose"}


def packages() -> set[str]:
    return {p.parent.relative_to(ROOT).as_posix() for pkg in PACKAGES
            for p in (ROOT / pkg).rglob("__init__.py")} - {"seg2pose"}


def test_every_named_module_exists():
    missing = sorted(p for p in named_paths(DOC.read_text()) if not (ROOT / p).exists())
    assert missing == []


def test_every_module_and_package_is_described():
    text = DOC.read_text()
    named = named_paths(text)
    assert sorted(m for m in tree_modules() - named if not m.endswith("__init__.py")) == []
    headings = set(re.findall(r"^###\s+`([\w/]+)/`", text, re.M))
    assert sorted(packages() - headings) == []


def test_the_checker_sees_a_missing_module(tmp_path):
    assert named_paths("see `video/nothing.py` and s2p_review/none.py") == {
        "seg2pose/video/nothing.py", "s2p_review/none.py"}
