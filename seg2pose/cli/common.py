"""What the command families share: the help panels of ``s2p --help``, the options several
commands take (``typing.Annotated`` aliases: ``progress: Progress = True``) and option parsers."""

from __future__ import annotations

import functools
import inspect
import typing
from collections.abc import Callable
from typing import Annotated

import typer

from seg2pose.cli.keep_inputs import refuse_replacing_inputs
from seg2pose.core.errors import InputError

# the groups of ``s2p --help`` (typer's rich_help_panel)
SCENE = "Scene"
METHOD = "Method"
REVIEW = "Review"
ANNOTATION = "Annotation"
BATCH = "Batch"
SAFETY = "Safety"

# options of several commands, one help text each
Progress = Annotated[bool, typer.Option("--progress/--no-progress", help="show progress bars")]


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """``A:B`` (inclusive) -> (A, B); None stays None."""
    if text is None:
        return None
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = int(parts[0]), int(parts[1])
    except ValueError:
        raise InputError(f"expected A:B with integer frames, got {text!r}", field="--frames") from None
    if a < 0 or b < a:
        raise InputError(f"expected 0 <= A <= B, got {text!r}", field="--frames")
    return a, b


def _option_names(default, annotated: tuple) -> tuple[str, ...]:
    """The names a parameter's option is declared with: in its default
    (``x: int = typer.Option(0, "--x")``) or in an Annotated alias (``x: Progress = True``),
    where typer reads the first positional argument of ``typer.Option`` as a name, not as the
    default."""
    for info in annotated:
        if isinstance(info, typer.models.OptionInfo):
            first = (info.default,) if isinstance(info.default, str) else ()
            return first + tuple(info.param_decls or ())
    return tuple(getattr(default, "param_decls", None) or ())


def speaks_flags(command: Callable) -> Callable:
    """Wrap a command so that a library InputError about one of its parameters (raised with
    ``field`` = the parameter's name and no file) names the command-line option instead: the
    library speaks in parameters, the command layer in flags. Also refuses, before any work,
    an output that is, holds or is a part of one of the command's inputs (``keep_inputs``)."""
    flags: dict[str, str] = {}
    labels: dict[str, str] = {}  # how the command line names each parameter: --flag, or ARG
    hints = typing.get_type_hints(command, include_extras=True)
    for p in inspect.signature(command).parameters.values():
        decls = _option_names(p.default, getattr(hints.get(p.name), "__metadata__", ()))
        longs = [d.split("/")[0] for d in decls if d.startswith("--")]
        flag = longs[0] if longs else "--" + p.name.replace("_", "-")
        flags[p.name] = flag
        flags[flag[2:].replace("-", "_")] = flag
        positional = isinstance(p.default, typer.models.ArgumentInfo) or any(
            isinstance(i, typer.models.ArgumentInfo) for i in getattr(hints.get(p.name), "__metadata__", ()))
        labels[p.name] = p.name.upper() if positional else flag

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        refuse_replacing_inputs(kwargs, labels)  # before any work: no output replaces an input
        try:
            return command(*args, **kwargs)
        except InputError as e:
            if e.file is None and e.field is not None and e.field in flags:
                raise InputError(e.message, line=e.line, field=flags[e.field]) from None
            raise

    return wrapper
