"""``s2p synth``: generate a synthetic traffic scene folder."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def synth(
        out: Path = typer.Argument(..., help="scene folder to create"),
        frames: Optional[int] = typer.Option(None, "--frames", help="frames per split (train, val and test each); default from the preset"),
        seed: int = typer.Option(0, "--seed", help="random seed: the same seed gives byte-identical files"),
        rig: str = typer.Option("device", "--rig", help="camera device: device (10 m pole), device-8m, device-12m, or a rig JSON file"),
        video: bool = typer.Option(False, "--video", help="also render RGB frames to video/<camera>.mp4"),
        preset: str = typer.Option("small", "--preset", help="small (3 x 240 frames, seconds) or paper (3 x 7,000 frames, section 4.1)"),
        no_noise: bool = typer.Option(False, "--no-noise", help="perfect silhouettes instead of Mask R-CNN-like masks"),
        ids: str = typer.Option("road_user", "--ids", help="road_user: a road user keeps its id when it comes back (paper); visit: a new id for every pass"),
        workers: Optional[int] = typer.Option(None, "--workers", help="processes (default: one per core, at most 2)"),
        force: bool = typer.Option(False, "--force", help="overwrite OUT if it exists"),
        quiet: bool = typer.Option(False, "--quiet", help="no progress bars"),
    ) -> None:
        """Make a synthetic junction scene (the CARLA stand-in of paper 4.1): five-lens camera
        device, ground points, MOTS masks with detector noise, ground-truth poses, optional video."""
        import time

        from seg2pose.synth.generate import generate_scene
        from seg2pose.synth.noise import NoiseConfig

        t = time.perf_counter()
        path = generate_scene(out, preset=preset, frames=frames, seed=seed, rig=rig, video=video,
                              force=force, noise=NoiseConfig.off() if no_noise else None,
                              progress=not quiet, workers=workers, ids=ids)
        typer.echo(f"wrote scene {path} in {time.perf_counter() - t:.1f} s")
