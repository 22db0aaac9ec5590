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

from seg2pose.core.errors import S2PError

# parameters that name what a command reads (a "C=PATH" value names PATH) and what it writes
INPUTS = frozenset({"scene", "src", "files", "ground", "source", "points", "aerial", "world_file",
                    "survey", "video", "calibration", "coco", "models", "from_models", "run",
                    "file", "rrd", "tracks", "csv", "conflicts", "r90"})
OUTPUTS = frozenset({"out", "save", "screenshot", "pet_only", "conflict_map", "tct_chart", "review"})

# what a scene folder holds that no command makes again from the rest (io/scene.py, io/run.py)
SCENE_PARTS = ("scene.json", "masks", "gt", "video", "annotations")
RUN_PARTS = ("poses.csv", "views.csv", "run.json")


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


def _parts(folder: Path) -> list[Path]:
    """The parts of ``folder`` that must not be replaced when it is a scene or run folder read
    by the command (the scene's ground points file by its scene.json's name for it)."""
    if (folder / "scene.json").is_file():
        names = list(SCENE_PARTS)
        try:
            import json

            g = json.loads((folder / "scene.json").read_text(encoding="utf-8")).get("ground_points")
            names.append(g if isinstance(g, str) and g else "ground_points.csv")
        except (OSError, ValueError, AttributeError):
            names.append("ground_points.csv")
        return [folder / n for n in names if (folder / n).exists()]
    if (folder / "run.json").is_file():
        return [folder / n for n in RUN_PARTS if (folder / n).exists()]
    return []


def refuse_replacing_inputs(kwargs: dict, labels: dict[str, str]) -> None:
    """One line (S2PError) when an output parameter's value is an input, holds one, or is a
    part of an input scene or run folder (``SCENE_PARTS``, ``RUN_PARTS``); ``labels``:
    parameter name -> how the command line names it (``--run``, ``SCENE``), for the message."""
    inputs = [(name, _real(t)) for name in INPUTS & kwargs.keys() for t in _paths(kwargs[name])
              if t and os.path.lexists(t)]
    if not inputs:
        return
    for oname in OUTPUTS & kwargs.keys():
        for text in _paths(kwargs[oname]):
            out = _real(text)
            for iname, src in inputs:
                what = f"{labels.get(iname, iname)} {src}"
                if out == src:
                    raise S2PError(f"{text}: is this command's input ({what}); replacing it would lose "
                                   "it: choose another output")
                if out in src.parents:
                    raise S2PError(f"{text}: holds this command's input ({what}); replacing it would lose "
                                   "it: choose another output")
                for part in _parts(src) if src.is_dir() else []:
                    if out == part or out in part.parents:
                        kind = "scene" if (src / "scene.json").is_file() else "run"
                        where = " (runs go under SCENE/out/)" if kind == "scene" else ""
                        raise S2PError(f"{text}: is the {part.name} of the {kind} {src} ({labels.get(iname, iname)}), "
                                       f"which no command makes again: choose another output{where}")
