"""The ``s2p`` command. Each family of commands lives beside its code and registers itself
here (``register(app)``); this module is the composition root, so it may import them all."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import typer

from seg2pose.errors import S2PError

app = typer.Typer(
    name="s2p",
    help="s2p: world-coordinate pose tracks of road users from instance-segmentation masks "
         "(the Seg2Pose method). Scene folders hold calibration, ground points, masks and "
         "ground truth; runs hold pose tracks; recordings open in the Rerun viewer.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# command families: module -> has register(app)
COMMAND_MODULES = [
    "seg2pose.io.cli",
    "seg2pose.synth.cli",
    "seg2pose.method_cli",
    "s2p_review.cli",
    "seg2pose.demo",
]


@app.callback()
def _root() -> None:
    """s2p: the Seg2Pose tool. Run ``s2p COMMAND --help`` for a command's options."""


@app.command()
def info(scene: Path = typer.Argument(..., help="scene folder")) -> None:
    """Summarise a scene folder: cameras, configurations, classes, ground points, files."""
    from seg2pose.io.scene import load_scene

    s = load_scene(scene)
    typer.echo(f"scene {s.name!r} at {s.root}  fps={s.fps:g}  fingerprint={s.fingerprint()}")
    typer.echo(f"ground: {len(s.ground_points)} points, z in [{s.ground.z_min:.2f}, {s.ground.z_max:.2f}] m")
    for c in s.cameras.values():
        cen = c.center
        typer.echo(f"camera {c.name}: {c.width}x{c.height}  f={c.K[0, 0]:.1f}px  centre=({cen[0]:.2f}, "
                   f"{cen[1]:.2f}, {cen[2]:.2f}) m  masks={'yes' if s.masks_path(c.name).exists() else 'no'}"
                   f"  video={'yes' if s.video_path(c.name) else 'no'}")
    for k, v in s.rig.configs.items():
        typer.echo(f"config {k}: {', '.join(v)}")
    for c in s.classes:
        typer.echo(f"class {c.id} {c.name}: default height {c.default_height:.3f} m")
    for k, (a, b) in s.splits.items():
        typer.echo(f"split {k}: frames {a}..{b}")
    typer.echo(f"ground truth: {'yes' if s.gt_path.exists() else 'no'}")


for _mod in COMMAND_MODULES:
    try:
        _m = importlib.import_module(_mod)
    except ModuleNotFoundError as e:  # a family not built yet, or an optional dependency missing
        if e.name and (e.name == _mod or _mod.startswith(e.name)):
            continue
        raise
    _m.register(app)


def main() -> None:
    """Entry point: S2PError becomes a one-line message and exit code 2 (no traceback)."""
    try:
        app()
    except S2PError as e:
        typer.secho(f"error: {e}", fg=typer.colors.RED, err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted; finished files are kept, partial ones were not written",
                    fg=typer.colors.YELLOW, err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
