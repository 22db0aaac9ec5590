"""Annotation commands: ``s2p annotate SCENE`` starts the annotation app; the ``annotate``
family also holds the project's other commands (``s2p annotate export ...``).

``s2p annotate SCENE`` is the family's default: when the first argument is not one of its
commands it is taken as a scene folder for ``s2p annotate open``.
"""

from __future__ import annotations

from pathlib import Path

import typer
from typer.core import TyperGroup

from seg2pose.cli.common import ANNOTATION


class _DefaultOpen(TyperGroup):
    """A group whose unknown first argument goes to its ``open`` command (``s2p annotate SCENE``)."""

    def parse_args(self, ctx, args):
        if args and not args[0].startswith("-") and args[0] not in self.commands:
            args = ["open", *args]
        return super().parse_args(ctx, args)


annotate_app = typer.Typer(cls=_DefaultOpen, no_args_is_help=True, help=(
    "Annotate a scene: keyframes placed by clicking road users in the camera images, "
    "interpolation in between (the T-Analyst replacement). `s2p annotate SCENE` opens the app."))


@annotate_app.command("open")
def open_app(
    scene: Path = typer.Argument(..., help="scene folder to annotate (edits go to SCENE/annotations/)"),
    run: Path | None = typer.Option(None, "--run", help="run folder of this scene (made by `s2p run`): its estimates are shown, can be accepted as keyframes and drive suggestions"),
    camera: list[str] = typer.Option([], "--camera", help="cameras to show (default: all)"),
    port: int | None = typer.Option(None, "--port", help="local port of the app (default: a free one)"),
    browser: bool = typer.Option(True, "--browser/--no-browser", help="open the app in your web browser"),
    native: bool = typer.Option(False, "--native", help="also show the recording in the native Rerun viewer (display only; clicks come from the page)"),
) -> None:
    """Start the annotation app on this computer (no internet, no account) and print its URL:
    the Rerun viewer with the cameras, the annotation's boxes and the run's estimates, and a
    panel of tracks, keyframes and actions with their keyboard shortcuts. Every edit is
    journalled at once; stop with Ctrl-C."""
    from annotate.app.serve import run_app

    run_app(scene, run, list(camera) or None, port=port, browser=browser, native=native,
            echo=typer.echo)


def register(app: typer.Typer) -> None:
    app.add_typer(annotate_app, name="annotate", rich_help_panel=ANNOTATION)
