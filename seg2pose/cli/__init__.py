"""The ``s2p`` command: the command layer, and the only part of ``seg2pose`` that may import
``s2p_review`` and ``annotate``.

One module per family of commands, each with ``register(app)``; they are imported and
registered here by name, so a reader (and any tool) sees what depends on what. ``s2p --help``
groups the commands in panels (``seg2pose.cli.common``): scene, method, review, annotation,
batch, safety.

A command imports the libraries it runs inside its function: ``s2p`` imports every command
module at start, and ``s2p --help`` should not wait for torch, scipy, OpenCV or Rerun
(tests/system/test_architecture.py checks that starting the command layer loads none of them).
"""

from __future__ import annotations

import sys

import typer

from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import os_error_message, unfinished_outputs

app = typer.Typer(
    name="s2p",
    help="s2p: world-coordinate pose tracks of road users from instance-segmentation masks "
         "(the Seg2Pose method). Scene folders hold calibration, ground points, masks and "
         "ground truth; runs hold pose tracks; recordings open in the Rerun viewer.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """s2p: the Seg2Pose tool. Run ``s2p COMMAND --help`` for a command's options."""


from seg2pose.cli import annotation, batch, calibration, demo, evaluation, method, review, safety, scene, video  # noqa: E402  (after app exists)

scene.register(app)
calibration.register(app)
video.register(app)
method.register(app)
evaluation.register(app)
review.register(app)
demo.register(app)
annotation.register(app)
batch.register(app)
safety.register(app)

INTERRUPTED = 130  # the shell's code for a command stopped by Ctrl-C (128 + SIGINT)


def main(argv: list[str] | None = None) -> None:
    """Entry point. An S2PError becomes a one-line message and exit code 2 (no traceback);
    Ctrl-C one line and exit code 130 (finished files stay; partial ones were never renamed
    into place)."""
    unfinished_outputs(forget=True)  # the outputs this command cuts short, for its last line
    try:
        rc = app(args=argv, standalone_mode=False)
    except S2PError as e:
        typer.secho(f"error: {e}", fg=typer.colors.RED, err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        rc = INTERRUPTED
    except OSError as e:  # the disk, not the input: still one line (outputs are atomic)
        cut = unfinished_outputs()
        typer.secho(f"error: {os_error_message(e, cut[-1] if cut else None)}", fg=typer.colors.RED,
                    err=True)
        sys.exit(2)
    except typer.Abort:  # end of input at a prompt
        typer.secho("aborted", fg=typer.colors.YELLOW, err=True)
        sys.exit(1)
    except typer.TyperException as e:  # usage errors: shown as typer shows them
        _show_typer_error(e)
        sys.exit(e.exit_code)
    # typer turns Ctrl-C into Exit(130), which standalone_mode=False returns as the code
    if rc == INTERRUPTED:
        cut = ", ".join(map(str, unfinished_outputs()))
        typer.secho(f"interrupted; {cut + ' not written (left as it was); ' if cut else ''}finished "
                    "files are kept, partial ones were not written", fg=typer.colors.YELLOW, err=True)
        sys.exit(INTERRUPTED)
    sys.exit(rc if isinstance(rc, int) else 0)


def _show_typer_error(e: typer.TyperException) -> None:
    """As typer's standalone mode shows it: a usage error (a ClickException of the click that
    typer >= 0.26 vendors) with rich where installed, else its own ``show``; another typer
    error (which has neither ``show`` nor what rich formats) as one line."""
    from typer._click.exceptions import ClickException  # what typer raises for usage errors

    if not isinstance(e, ClickException):
        typer.secho(f"error: {e.format_message()}", fg=typer.colors.RED, err=True)
        return
    try:
        from typer import rich_utils
    except ImportError:  # typer without rich
        e.show()
        return
    rich_utils.rich_format_error(e)


if __name__ == "__main__":
    main()
