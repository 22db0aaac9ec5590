"""Issue 38: every file s2p writes goes through ``seg2pose/io/`` (atomic outputs, locks, no
link followed). This walks the syntax tree of every module of the packages and fails on a
write anywhere else: ``open``/``io.open``/``Path.open``/``av.open`` with a writing mode,
``os.open`` with writing flags, ``write_text``, ``write_bytes``, ``numpy.save*``/``savetxt``,
``torch.save``, ``shutil.copy*``/``copytree``/``move``, ``os.replace``/``os.rename``/
``Path.replace``/``Path.rename``, ``os.link``/``os.symlink``, ``cv2.imwrite``,
``json.dump``/``pickle.dump`` into a file, ``tofile``, ``to_csv``, ``imageio``/``PIL`` saves.
The allowlist below is short, each entry with its reason: places where a writer is handed a
path inside a partial folder of an ``atomic.outputs`` set (a third-party library that only
takes a path), or the lock primitive ``seg2pose.io`` itself is built on."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ["seg2pose", "annotate", "s2p_review"]
ALLOWED_DIR = "seg2pose/io/"

# "path:call" -> why it may write outside seg2pose/io/ (every one writes inside a partial
# folder of an atomic.outputs set, or is the lock primitive io is built on)
ALLOW = {
    "seg2pose/core/locks.py:os.open": "the lock files themselves (O_EXCL / O_NOFOLLOW); "
                                      "seg2pose.io.atomic.output_lock is built on it",
    "seg2pose/synth/video.py:cv2.VideoWriter": "OpenCV takes a path: atomic_path's temporary",
    "seg2pose/training/train.py:torch.save": "the resume state, into atomic_path's temporary",
    "s2p_review/video_asset.py:av.open": "PyAV takes a path: atomic_path's temporary",
    "s2p_review/frame_code.py:cv2.VideoWriter": "OpenCV takes a path: atomic_path's temporary",
    "s2p_review/frame_code.py:av.open": "PyAV takes a path: atomic_path's temporary",
    "s2p_review/recording_images.py:np.savez": "into atomic_open's file object",
    "s2p_review/annotated_mcap.py:av.open": "muxes into memory (io.BytesIO), not a file",
}

_MODULE_CALLS = {
    "os.replace", "os.rename", "os.renames", "os.link", "os.symlink", "os.truncate",
    "shutil.copy", "shutil.copy2", "shutil.copyfile", "shutil.copytree", "shutil.move",
    "np.save", "np.savez", "np.savez_compressed", "np.savetxt", "numpy.save", "numpy.savez",
    "numpy.savez_compressed", "numpy.savetxt", "torch.save", "cv2.imwrite", "cv2.VideoWriter",
    "json.dump", "pickle.dump", "imageio.imwrite", "imageio.v3.imwrite", "iio.imwrite",
}
_METHODS = {"write_text", "write_bytes", "tofile", "to_csv", "to_parquet", "save_file"}
_WRITE_FLAGS = {"O_WRONLY", "O_RDWR", "O_CREAT", "O_TRUNC", "O_APPEND"}


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    if isinstance(node, ast.Name):
        return node.id
    return "?"


def _mode(call: ast.Call) -> ast.AST | None:
    for k in call.keywords:
        if k.arg == "mode":
            return k.value
    return call.args[1] if len(call.args) > 1 else None


def _writes_mode(mode: ast.AST | None) -> bool:
    if mode is None:
        return False
    if isinstance(mode, ast.Constant) and isinstance(mode.value, str):
        return bool(set(mode.value) & set("wax+"))
    return True  # a mode computed at run time: it may write


def write_calls(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, call) of every call in ``tree`` that writes a file (see the module docstring)."""
    out = []
    for n in ast.walk(tree):
        if not isinstance(n, ast.Call):
            continue
        name = _dotted(n.func)
        last = name.rsplit(".", 1)[-1]
        hit = False
        if name == "os.open":
            flags = {a.attr for a in ast.walk(n.args[1]) if isinstance(a, ast.Attribute)} if len(n.args) > 1 else set()
            hit = bool(flags & _WRITE_FLAGS) or not flags
        elif name in _MODULE_CALLS:
            hit = True
        elif last == "open":  # open(), io.open(), Path.open(mode), av.open(path, mode), ...
            m = _mode(n)
            a0 = n.args[0] if n.args else None
            if (isinstance(n.func, ast.Attribute) and name != "io.open" and isinstance(a0, ast.Constant)
                    and isinstance(a0.value, str) and set(a0.value) <= set("rwxabt+")):
                m = a0  # Path.open("wb")
            hit = _writes_mode(m)
        elif isinstance(n.func, ast.Attribute) and last in _METHODS:
            hit = True
        elif isinstance(n.func, ast.Attribute) and last in ("replace", "rename") \
                and len(n.args) == 1 and not n.keywords:  # Path.replace(target); str.replace has 2
            hit = True
        elif isinstance(n.func, ast.Attribute) and last in ("savez", "savez_compressed", "imwrite"):
            hit = True
        if hit:
            out.append((n.lineno, name))
    return out


def violations(root: Path = ROOT) -> list[str]:
    out = []
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel.startswith(ALLOWED_DIR):
                continue
            for line, call in write_calls(ast.parse(path.read_text(encoding="utf-8"))):
                if f"{rel}:{call}" not in ALLOW:
                    out.append(f"{rel}:{line}: {call}")
    return out


def test_every_write_goes_through_seg2pose_io():
    found = violations()
    assert found == [], ("writes outside seg2pose/io/ (use seg2pose.io.atomic: outputs, "
                         "atomic_write_text, or seg2pose.io.nofollow for a file in a partial "
                         "folder):\n" + "\n".join(found))


def test_the_check_finds_each_kind_of_write(tmp_path):
    """The walker itself, on a module with one write of each kind and some look-alikes."""
    src = '''
import os, shutil, json, numpy as np, torch, cv2
from pathlib import Path
open("a", "w"); open("a", "rb"); open("a"); open("a", mode="a"); open("a", m)
Path("a").open("wb"); Path("a").open(); Path("a").write_text("x"); Path("a").write_bytes(b"")
np.save("a", x); np.savez("a", x=1); torch.save(x, "a"); cv2.imwrite("a.png", x)
shutil.copy2("a", "b"); shutil.copytree("a", "b"); os.replace("a", "b"); Path("a").rename("b")
json.dump(x, f); json.dumps(x); "ab".replace("a", "b"); x.copy(); replace(cfg, a=1)
os.open("a", os.O_RDONLY); os.open("a", os.O_WRONLY | os.O_CREAT)
'''
    got = sorted(c for _, c in write_calls(ast.parse(src)))
    assert got == sorted(["open", "open", "open", "?.open", "?.write_text", "?.write_bytes", "np.save",
                   "np.savez", "torch.save", "cv2.imwrite", "shutil.copy2", "shutil.copytree",
                   "os.replace", "?.rename", "json.dump", "os.open"])
