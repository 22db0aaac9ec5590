"""The architecture of docs/ARCHITECTURE.md, checked on the source: which package may import
which (every import statement, also those inside functions), no import cycles between modules,
no module using another module's private names, and a command layer that starts light.

The checker is shown to fail: on a planted layer violation, a planted cycle (one side of it an
import inside a function) and a planted private import, in a small fake tree under tmp_path."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ("seg2pose", "s2p_review", "annotate")

# which package may import which: each package imports only the packages listed (its own
# modules always). Below io: core -> structures -> geometry -> io; above it video, method and
# synth; then training, eval, batch; the command layer on top. Root modules of a package
# (``seg2pose/__init__.py``) count as the package ``seg2pose``.
_BASE = {"seg2pose.core", "seg2pose.structures", "seg2pose.geometry", "seg2pose.io"}
MAY_IMPORT = {
    "seg2pose": {"seg2pose.core"},
    "seg2pose.core": set(),
    "seg2pose.structures": {"seg2pose.core"},
    "seg2pose.geometry": {"seg2pose.core", "seg2pose.structures"},
    "seg2pose.io": {"seg2pose.core", "seg2pose.structures", "seg2pose.geometry"},
    "seg2pose.video": _BASE,
    "seg2pose.method": _BASE,
    "seg2pose.synth": _BASE,
    "seg2pose.safety": _BASE,
    "seg2pose.training": _BASE | {"seg2pose.method", "seg2pose.video", "seg2pose.synth"},
    "seg2pose.eval": _BASE | {"seg2pose.method"},
    "seg2pose.batch": _BASE | {"seg2pose.method", "seg2pose.video", "seg2pose.eval"},
    "seg2pose.cli": {"seg2pose", "seg2pose.core", "seg2pose.structures", "seg2pose.geometry",
                     "seg2pose.io", "seg2pose.video", "seg2pose.method", "seg2pose.synth", "seg2pose.safety",
                     "seg2pose.training", "seg2pose.eval", "seg2pose.batch", "s2p_review", "annotate"},
    "s2p_review": _BASE | {"seg2pose.eval", "seg2pose.safety"},  # conflicts shown in a review
    "annotate": _BASE | {"seg2pose.eval", "seg2pose.safety"},  # the app: road users' footprints
}
# the annotation app's page shows the scene through s2p_review's logging, as `s2p review`
# does, and draws the large camera's picture from the same video asset and columns; the
# annotation engine and the app's controller stay free of it
EXCEPTIONS = {("annotate.app.session", "s2p_review"), ("annotate.app.notebook", "s2p_review"),
              ("annotate.app.frame_image", "s2p_review"), ("annotate.app.viewer_cache", "s2p_review")}
# third-party packages only some layers may use: the viewer's SDK belongs to the review and
# annotation packages and the command layer
ONLY_IN = {"rerun": {"s2p_review", "annotate", "seg2pose.cli"}}
# what the command layer must not load at start (s2p --help): each takes a second or more
HEAVY = ("torch", "scipy", "cv2", "rerun", "matplotlib", "pycocotools", "ray", "marimo")


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules(root: Path) -> dict[str, Path]:
    """{module name: file} of the project's packages under ``root``."""
    return {module_name(p, root): p for pkg in PROJECT if (root / pkg).is_dir()
            for p in sorted((root / pkg).rglob("*.py"))}


def imports(path: Path, mod: str, known: dict) -> list[tuple[int, str, list[str]]]:
    """(line, imported module, names taken from it) of every import statement in ``path``,
    module level or inside functions; relative imports resolved; ``from a import b`` where
    ``a.b`` is a module of ``known`` gives module ``a.b``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    pkg = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[:len(pkg) - node.level + 1] + ([base] if base else []))
            rest = []
            for a in node.names:
                if f"{base}.{a.name}" in known:
                    out.append((node.lineno, f"{base}.{a.name}", []))
                else:
                    rest.append(a.name)
            if rest or not node.names:
                out.append((node.lineno, base, rest))
    return out


def package_of(mod: str) -> str:
    """The row of ``MAY_IMPORT`` a module belongs to: ``seg2pose.<package>``, ``seg2pose``
    for the root modules, else its top-level package (``s2p_review``, ``annotate``)."""
    parts = mod.split(".")
    if parts[0] == "seg2pose" and len(parts) > 1 and f"seg2pose.{parts[1]}" in MAY_IMPORT:
        return f"seg2pose.{parts[1]}"
    return parts[0]


def within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def layer_violations(root: Path = ROOT) -> list[str]:
    known = modules(root)
    bad = []
    for mod, path in known.items():
        mine = package_of(mod)
        for line, name, _ in imports(path, mod, known):
            where = f"{path.relative_to(root)}:{line}: imports {name}"
            top = name.split(".")[0]
            if top in ONLY_IN and not any(within(mod, ok) for ok in ONLY_IN[top]):
                bad.append(f"{where} (only {', '.join(sorted(ONLY_IN[top]))} may use {top})")
            if top not in PROJECT:
                continue
            theirs = package_of(name)
            if theirs == mine or (mod, theirs) in EXCEPTIONS:
                continue
            if theirs not in MAY_IMPORT.get(mine, set()):
                bad.append(f"{where} ({mine} may import only "
                           f"{', '.join(sorted(MAY_IMPORT.get(mine, ()))) or 'nothing of the project'})")
    return bad


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    """module -> the project modules it imports (anywhere in it)."""
    known = modules(root)
    return {mod: {name for _, name, _ in imports(path, mod, known) if name in known and name != mod}
            for mod, path in known.items()}


def cycles(root: Path = ROOT) -> list[list[str]]:
    """The import cycles among the project's modules (each as a path a -> ... -> a)."""
    g = graph(root)
    found, state, stack = [], {}, []

    def visit(m: str) -> None:
        state[m] = "open"
        stack.append(m)
        for n in sorted(g[m]):
            if state.get(n) == "open":
                found.append(stack[stack.index(n):] + [n])
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = "done"

    for m in sorted(g):
        if m not in state:
            visit(m)
    return found


def private_uses(root: Path = ROOT) -> list[str]:
    """Uses of another module's private names (``_x``, not dunders): ``from m import _x`` and
    ``m._x`` where ``m`` names a project module."""
    known = modules(root)
    bad = []
    for mod, path in known.items():
        aliases = {}
        for line, name, taken in imports(path, mod, known):
            for t in taken:
                if t.startswith("_") and not t.startswith("__") and name != mod:
                    bad.append(f"{path.relative_to(root)}:{line}: imports {name}.{t}")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                aliases.update({a.asname: a.name for a in node.names if a.asname and a.name in known})
            elif isinstance(node, ast.ImportFrom) and node.module:
                aliases.update({a.asname or a.name: f"{node.module}.{a.name}" for a in node.names
                                if f"{node.module}.{a.name}" in known})
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                bad.append(f"{path.relative_to(root)}:{node.lineno}: uses {aliases[node.value.id]}.{node.attr}")
    return bad


# ----------------------------------------------------------------------------------------------


def test_every_package_is_in_the_table():
    packages = {package_of(m) for m in modules(ROOT)}
    assert packages == set(MAY_IMPORT), packages ^ set(MAY_IMPORT)
    assert len(modules(ROOT)) > 100


def test_allowed_imports():
    assert layer_violations() == []


def test_no_import_cycles():
    assert cycles() == []


def test_no_private_names_across_modules():
    assert private_uses() == []


def test_the_command_layer_starts_light():
    """``s2p`` imports every command module at start: none of them may load the heavy
    libraries at module level (they are imported inside the commands)."""
    code = ("import sys, seg2pose.cli; "
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == []


def _fake_tree(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    for d in {p.parent for p in root.rglob("*.py")}:
        (d / "__init__.py").touch()


def test_the_checker_fails_on_planted_faults(tmp_path):
    """Not vacuous: a layer violation (also inside a function, also relative), a cycle whose one
    side is an import inside a function, and a private import are each reported."""
    _fake_tree(tmp_path, {
        "seg2pose/core/ok.py": "import numpy\n",
        "seg2pose/io/bad.py": ("def f():\n    from ..method import pipeline\n"
                               "    import rerun as rr\n"),
        "seg2pose/method/pipeline.py": "from seg2pose.method import net\n",
        "seg2pose/method/net.py": "def g():\n    from seg2pose.method.pipeline import run\n",
        "seg2pose/method/sparse.py": "from seg2pose.core.ok import _secret\n",
        "seg2pose/method/ood.py": "from seg2pose.core import ok\n\nx = ok._hidden + ok.public\n",
    })
    assert [v.split(" (")[0] for v in layer_violations(tmp_path)] == [
        "seg2pose/io/bad.py:2: imports seg2pose.method.pipeline",
        "seg2pose/io/bad.py:3: imports rerun"]
    assert cycles(tmp_path) == [["seg2pose.method.pipeline", "seg2pose.method.net", "seg2pose.method.pipeline"]]
    assert private_uses(tmp_path) == ["seg2pose/method/ood.py:3: uses seg2pose.core.ok._hidden",
                                      "seg2pose/method/sparse.py:1: imports seg2pose.core.ok._secret"]
    # and the clean tree is clean
    for rel in ("io/bad.py", "method/net.py", "method/sparse.py", "method/ood.py"):
        (tmp_path / "seg2pose" / rel).unlink()
    assert layer_violations(tmp_path) == cycles(tmp_path) == private_uses(tmp_path) == []
