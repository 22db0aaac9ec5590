"""``s2p synth``: generate a synthetic traffic scene folder."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from seg2pose.errors import InputError

NOISE_KEYS = ["miss_rate", "min_area", "small_area", "small_miss", "occlusion_miss", "merge_rate",
              "class_confusion",
              "dilate_px", "mask_resolution", "boundary_jitter", "fragment_rate"]


def parse_noise(items: list[str]) -> dict:
    """["miss_rate=0.05", ...] -> {"miss_rate": 0.05, ...} (ints for pixel counts)."""
    out = {}
    for it in items:
        key, sep, val = it.partition("=")
        key = key.strip()
        if not sep or key not in NOISE_KEYS:
            raise InputError(f"expected KEY=VALUE with KEY one of {', '.join(NOISE_KEYS)}, got {it!r}",
                             field="--noise")
        try:
            out[key] = int(val) if key in ("min_area", "small_area", "mask_resolution") else float(val)
        except ValueError:
            raise InputError(f"{key} needs a number, got {val!r}", field="--noise") from None
    return out


def register(app: typer.Typer) -> None:
    @app.command()
    def synth(
        out: Path = typer.Argument(..., help="scene folder to create"),
        frames: Optional[int] = typer.Option(None, "--frames", help="frames per split (train, val and test each); default from the preset"),
        seed: int = typer.Option(0, "--seed", help="random seed: the same seed gives byte-identical files"),
        rig: str = typer.Option("device", "--rig", help="camera device: device (10 m pole), device-8m, device-12m, or a rig JSON file"),
        video: bool = typer.Option(False, "--video", help="also render RGB frames to video/<camera>.mp4"),
        preset: str = typer.Option("small", "--preset", help="small (3 x 240 frames, seconds; tests and the demo), bench (3 x 960 frames, about a minute; the accuracy benchmark) or paper (3 x 7,000 frames, section 4.1)"),
        no_noise: bool = typer.Option(False, "--no-noise", help="perfect silhouettes instead of Mask R-CNN-like masks"),
        noise: list[str] = typer.Option([], "--noise", help="a detector-noise knob KEY=VALUE (repeatable), e.g. --noise miss_rate=0.05; keys: " + ", ".join(NOISE_KEYS)),
        distortion: Optional[str] = typer.Option(None, "--distortion", help="radial lens distortion K1,K2 of the device's lenses (off by default)"),
        ids: str = typer.Option("road_user", "--ids", help="road_user: a road user keeps its id when it comes back (paper); visit: a new id for every pass"),
        match: str = typer.Option("center", "--match", help="center: keep a mask only when the road user's true 3D centre projects inside it (paper 4.1's association); all: every visible mask"),
        workers: Optional[int] = typer.Option(None, "--workers", help="processes (default: one per core, at most 2)"),
        force: bool = typer.Option(False, "--force", help="overwrite OUT if it exists"),
        quiet: bool = typer.Option(False, "--quiet", help="no progress bars"),
    ) -> None:
        """Make a synthetic junction scene (the CARLA stand-in of paper 4.1): five-lens camera
        device, ground points, MOTS masks with detector noise, ground-truth poses, optional video."""
        import time

        from seg2pose.synth.generate import generate_scene
        from seg2pose.synth.noise import NoiseConfig

        cfg = NoiseConfig.off() if no_noise else NoiseConfig()
        if noise:
            cfg = NoiseConfig.from_dict({**cfg.to_dict(), **parse_noise(noise)})
        dist = None
        if distortion:
            try:
                dist = tuple(float(v) for v in distortion.split(","))
            except ValueError:
                raise InputError(f"expected K1,K2 numbers, got {distortion!r}", field="--distortion") from None
            if len(dist) == 1:
                dist = (dist[0], 0.0)
        t = time.perf_counter()
        path = generate_scene(out, preset=preset, frames=frames, seed=seed, rig=rig, video=video,
                              force=force, noise=cfg, progress=not quiet, workers=workers,
                              ids=ids, distortion=dist, match=match)
        typer.echo(f"wrote scene {path} in {time.perf_counter() - t:.1f} s")
