"""The allowed-imports rule of docs/ARCHITECTURE.md, checked on the source (every import
statement, also those inside functions)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
IO_MAY_USE = {"seg2pose.core.errors", "seg2pose.core.say", "seg2pose.geometry.camera", "seg2pose.geometry.ground",
              "seg2pose.structures.masks"}


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """(line, imported module) of every import in ``path``; relative imports resolved;
    ``from a import b`` gives ``a.b`` too (b may be a module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    pkg = module_name(path, root).split(".")
    if path.name != "__init__.py":
        pkg = pkg[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[:len(pkg) - node.level + 1] + ([base] if base else []))
            out.append((node.lineno, base))
            out += [(node.lineno, f"{base}.{a.name}") for a in node.names]
    return out


def sources(package: str, root: Path = ROOT) -> list[Path]:
    return sorted((root / package).rglob("*.py"))


def within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def violations(package: str, rule, root: Path = ROOT) -> list[str]:
    bad = []
    for p in sources(package, root):
        for line, name in imports(p, root):
            why = rule(module_name(p, root), name)
            if why:
                bad.append(f"{p.relative_to(root)}:{line}: imports {name} ({why})")
    return bad


def seg2pose_rule(mod: str, name: str) -> str | None:
    if within(mod, "seg2pose.cli"):
        return None
    for forbidden in ("s2p_review", "annotate", "rerun", "seg2pose.cli"):
        if within(name, forbidden):
            return f"only the command layer seg2pose.cli may import {forbidden}"
    if within(mod, "seg2pose.io") and within(name, "seg2pose") and not within(name, "seg2pose.io") \
            and not any(within(name, ok) for ok in IO_MAY_USE) and name != "seg2pose":
        return "seg2pose.io imports nothing of the method"
    return None


def review_rule(mod: str, name: str) -> str | None:
    if within(name, "annotate") or within(name, "seg2pose.cli"):
        return "s2p_review uses seg2pose's library, not annotate or the command layer"
    return None


def annotate_rule(mod: str, name: str) -> str | None:
    # the app's page (annotate.app.session) shows the scene through s2p_review's logging, as
    # `s2p review` does; the engine and the app's controller stay free of it
    if mod in ("annotate.app.session", "annotate.app.notebook") and within(name, "s2p_review"):
        return None
    if within(name, "s2p_review") or within(name, "seg2pose.cli"):
        return "annotate uses seg2pose's library, not s2p_review or the command layer"
    return None


@pytest.mark.parametrize("package,rule", [("seg2pose", seg2pose_rule), ("s2p_review", review_rule),
                                          ("annotate", annotate_rule)])
def test_allowed_imports(package, rule):
    assert sources(package), f"no sources under {package}"
    assert violations(package, rule) == []


def test_the_checker_sees_violations(tmp_path):
    """The rule is not vacuous: a module that breaks it, inside a function or relatively, is
    reported with its line."""
    pkg = tmp_path / "seg2pose" / "io"
    pkg.mkdir(parents=True)
    (tmp_path / "seg2pose" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "bad.py").write_text("import numpy\n\ndef f():\n    from ..normal import normal_positions\n"
                                "    import rerun as rr\n    from seg2pose.io import atomic\n")
    got = violations("seg2pose", seg2pose_rule, tmp_path)
    assert [g.split(" (")[0] for g in got] == [
        "seg2pose/io/bad.py:4: imports seg2pose.geometry.normal",
        "seg2pose/io/bad.py:4: imports seg2pose.geometry.normal.normal_positions",
        "seg2pose/io/bad.py:5: imports rerun"]
