"""No output replaces what the command reads: refused in one line before any work.

``--force`` replaces an output; named by a slip of the keyboard, that output could be the
command's own input (``s2p conflicts RUN -o RUN/poses.csv --force``), hold it (``s2p run SCENE
-o SCENE --force`` replaced the whole scene folder, truth and masks with it, by a run folder), or
be a part of an input scene that no command makes again (``-o SCENE/gt``). Checked by the
parameters' names, for every command that ``speaks_flags`` wraps: the values of the input
parameters that name existing files or folders against those of the output parameters.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from seg2pose.core.errors import InputError, S2PError

# parameters that name what a command reads (a "C=PATH" value names PATH) and what it writes
INPUTS = frozenset({"scene", "src", "files", "ground", "source", "points", "aerial", "world_file",
                    "survey", "video", "calibration", "coco", "models", "from_models", "run",
                    "file", "rrd", "tracks", "csv", "conflicts", "r90"})
OUTPUTS = frozenset({"out", "save", "screenshot", "pet_only", "conflict_map", "tct_chart", "review"})

# what a scene folder holds that no command makes again from the rest, beside its scene.json
# and ground points file (io/scene_schema.py), and a run folder's own files (io/run.py)
SCENE_FOLDERS = ("masks", "gt", "video", "annotations")


def _paths(value) -> Iterable[str]:
    """The path texts in a parameter's value (a path, a text, a list of them; "C=PATH": PATH)."""
    if isinstance(value, (str, os.PathLike)):
        text = os.fspath(value)
        yield text.split("=", 1)[1] if "=" in text and not Path(text).exists() else text
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _paths(v)


def _real(p: str | Path) -> Path:
    return Path(os.path.realpath(p))


def _parts(folder: Path) -> tuple[str, list[Path]]:
    """("scene" or "run", the parts of ``folder`` that must not be replaced) when the input
    ``folder`` is a scene or run folder, else ("", []). The scene's ground points file is the
    one its scene.json names, as the reader takes it (``scene_fields``; the default name when
    the file does not read: the command itself then says why). Imported here, not at start:
    ``s2p --help`` loads no numpy (tests/system/test_architecture.py)."""
    from seg2pose.io.run import POSES_FILE, RUN_FILE, VIEWS_FILE
    from seg2pose.io.scene_schema import DEFAULT_GROUND_FILE, SCENE_FILE, scene_fields
    from seg2pose.io.text import load_json

    if not folder.is_dir():
        return "", []
    if (folder / SCENE_FILE).is_file():
        try:
            ground = scene_fields(load_json(folder / SCENE_FILE), folder, folder / SCENE_FILE).ground_file
        except InputError:
            ground = DEFAULT_GROUND_FILE
        kind, names = "scene", [SCENE_FILE, ground, *SCENE_FOLDERS]
    elif (folder / RUN_FILE).is_file():
        kind, names = "run", [POSES_FILE, VIEWS_FILE, RUN_FILE]
    else:
        return "", []
    return kind, [folder / n for n in names if (folder / n).exists()]


def refuse_replacing_inputs(kwargs: dict, labels: dict[str, str]) -> None:
    """One line (S2PError) when an output parameter's value is an input, holds one, or is a
    part of an input scene or run folder (``_parts``); ``labels``: parameter name -> how the
    command line names it (``--run``, ``SCENE``), for the message."""
    outs = [text for name in OUTPUTS & kwargs.keys() for text in _paths(kwargs[name])]
    if not outs:
        return
    inputs = [(labels.get(name, name), src, *_parts(src))
              for name in INPUTS & kwargs.keys() for t in _paths(kwargs[name])
              if t and os.path.lexists(t) for src in [_real(t)]]
    for text in outs:
        out = _real(text)
        for label, src, kind, parts in inputs:
            if out == src:
                raise S2PError(f"{text}: is this command's input ({label} {src}); replacing it would "
                               "lose it: choose another output")
            if out in src.parents:
                raise S2PError(f"{text}: holds this command's input ({label} {src}); replacing it would "
                               "lose it: choose another output")
            for part in parts:
                if out == part or out in part.parents:
                    where = " (runs go under SCENE/out/)" if kind == "scene" else ""
                    raise S2PError(f"{text}: is the {part.name} of the {kind} {src} ({label}), "
                                   f"which no command makes again: choose another output{where}")
