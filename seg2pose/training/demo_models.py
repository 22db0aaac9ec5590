"""The Seg2PoseNet models shipped for ``s2p demo`` (``seg2pose/data/demo_models/``): what they
are, whether they fit a scene, and the command that makes them again.

Why ship models: the demo scene (small preset, seed 0) has a 240-frame training split, and the
demo's own two-minute CPU training on it (``TrainConfig.demo()``) reaches only about 0.8x the
baseline's error, which undersells the method. The shipped models are the held-out protocol's
(``--protocol quick``: one ``lite-hr`` + mask-geometry model per class for the five lenses of
the device) trained by the project on **other scenes of the same junction and device**: the
``bench`` preset (960 frames per split), seeds ``TRAIN_SEEDS`` -- not the demo's seed 0 and no
held-out seed of docs/RESULTS.md. All seeds of the small and bench presets share the device's
calibration and the junction's ground; only the traffic and the sampled ground points differ.
With several seeds the demo averages their residuals (``checkpoint.Ensemble``).

Layout: ``demo_models.json`` (the manifest: classes, the cameras' fingerprint, the protocol,
the command, and per member folder its training scene, default heights and training wall
time) and one folder per training seed, ``bench-seed<N>/all__<class>.safetensors`` (the
checkpoint format of ``seg2pose.method.checkpoint``, weights stored as float16 to keep the
files small; "cameras_fingerprint" in their metadata marks them as made for the device, so any
scene of its cameras uses them without the other-scene warning) with ``.json`` sidecars.

Remake them (see the manifest's "train_s" for the measured time; about half an hour per seed
on the shared 2-core machine)::

    PYTHONPATH=. python -m seg2pose.training.demo_models /tmp/demo-models

which, per seed, runs ``s2p synth --preset bench --seed N``, ``s2p heights`` and three ``s2p
train --protocol quick --class C --threads 1`` (one process per class, in parallel), then
writes the float16 copies and the manifest here. Training on the CPU is deterministic for a
given torch build and thread count, so the command should give these files again (not checked
by a second training); a resumed training draws its rough-model pool from another point of
the random stream and gives slightly other models.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import torch

from seg2pose.core.errors import InputError, S2PError
from seg2pose.io.atomic import atomic_path, atomic_write_text
from seg2pose.io.scene import Scene, load_scene
from seg2pose.method.checkpoint import Checkpoint, ModelSet, model_filename

SHIPPED = Path(__file__).resolve().parent.parent / "data" / "demo_models"
MANIFEST = "demo_models.json"
TRAIN_PRESET = "bench"
TRAIN_SEEDS = (7, 8)  # not the demo scene's seed (0) and no held-out seed of docs/RESULTS.md
PROTOCOL = "quick"


def read_manifest(models_dir: Path = SHIPPED) -> dict:
    """The folder's manifest (``demo_models.json``); InputError naming the file if it is
    missing or not a JSON object with the keys the demo reads."""
    path = Path(models_dir) / MANIFEST
    if not path.exists():
        raise InputError("no manifest of shipped demo models", file=path)
    try:
        m = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"not readable JSON ({e})", file=path) from None
    for key in ("classes", "cameras_fingerprint", "members"):
        if not isinstance(m, dict) or key not in m:
            raise InputError(f"missing key {key!r}", file=path, field=key)
    if not m["members"] or not all(isinstance(x, dict) and "dir" in x and "trained_on" in x
                                   for x in m["members"]):
        raise InputError("expected a list of {dir, trained_on, ...}", file=path, field="members")
    return m


def model_folders(models_dir: Path = SHIPPED) -> list[Path]:
    """The member folders the manifest lists (one per training seed; averaged when several)."""
    return [Path(models_dir) / x["dir"] for x in read_manifest(models_dir)["members"]]


def describe(manifest: dict) -> str:
    """One line naming the models for a results table: protocol, training scenes."""
    t = [x["trained_on"] for x in manifest["members"]]
    seeds = " and ".join(str(x["seed"]) for x in t)
    return (f"shipped --protocol {manifest.get('protocol', PROTOCOL)} models trained on the "
            f"{t[0]['preset']} preset, seed{'s' if len(t) > 1 else ''} {seeds} "
            f"({t[0]['frames_per_split']} frames per split; not this scene)"
            + (", residuals averaged" if len(t) > 1 else ""))


def fit_problem(scene: Scene, models_dir: Path = SHIPPED) -> str | None:
    """None when the folder's models fit ``scene`` (the same class names in the same order,
    the same cameras' calibration, a loadable model for every camera and class); else one line
    saying what does not fit."""
    try:
        m = read_manifest(models_dir)
    except InputError as e:
        return str(e)
    if list(m["classes"]) != scene.class_names:
        return (f"the shipped models are for classes {', '.join(m['classes'])}; this scene has "
                f"{', '.join(scene.class_names)}")
    if m["cameras_fingerprint"] != scene.cameras_fingerprint():
        return (f"the shipped models were made for other cameras (fingerprint "
                f"{m['cameras_fingerprint']}, this scene's {scene.cameras_fingerprint()})")
    try:
        ModelSet.load(model_folders(models_dir), list(scene.cameras), scene.class_names,
                      cameras_fingerprint=scene.cameras_fingerprint())
    except S2PError as e:  # InputError is one: a missing, damaged or misfitting checkpoint
        return str(e)
    return None


def ship_member(models_src: Path, out: Path, scene: Scene) -> list[Path]:
    """Write float16 copies of the finished per-class checkpoints in ``models_src`` (trained
    on ``scene``) into the folder ``out``, marked as made for the device's cameras."""
    from safetensors.torch import save_file

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for cls in scene.class_names:
        src = models_src / model_filename("*", cls)
        ck = Checkpoint.load(src)
        if ck.info.get("complete") is not True:
            raise S2PError(f"{src}: its training did not finish; finish it first")
        ck.info["cameras_fingerprint"] = scene.cameras_fingerprint()
        meta = ck.metadata()
        # float16 halves the files; the demo's mean errors are the same to 0.1 mm
        # (docs/RESULTS.md, "The demo's shipped models")
        state = {k: v.detach().to(torch.float16 if v.is_floating_point() else v.dtype).cpu().contiguous()
                 for k, v in ck.net.state_dict().items()}
        dst = out / src.name
        with atomic_path(dst) as tmp:
            save_file(state, str(tmp), metadata={"s2p": json.dumps(meta)})
        atomic_write_text(dst.with_suffix(".json"), json.dumps(meta, indent=1) + "\n")
        written += [dst, dst.with_suffix(".json")]
    return written


def ship(members: list[tuple[Path, Scene, dict]], out: Path, facts: dict) -> list[Path]:
    """Ship trained models: for each (model folder, its training scene, facts such as the
    training time) float16 copies in ``out/<scene folder name>/``, then the manifest in
    ``out`` with ``facts`` (the command ...). All scenes must share cameras and classes.
    Returns the files written."""
    out = Path(out)
    written, listed = [], []
    first = members[0][1]
    for models_src, scene, member_facts in members:
        if (scene.cameras_fingerprint(), scene.class_names) != (first.cameras_fingerprint(), first.class_names):
            raise S2PError(f"{scene.root}: other cameras or classes than {first.root}")
        written += ship_member(Path(models_src), out / scene.root.name, scene)
        gen = scene.extra.get("generator", {})
        listed.append({"dir": scene.root.name,
                       "trained_on": {"preset": gen.get("preset"), "seed": gen.get("seed"),
                                      "frames_per_split": gen.get("frames_per_split"),
                                      "scene_fingerprint": scene.fingerprint()},
                       # the training scene's; the demo keeps its own scene's (measured better)
                       "default_heights": scene.default_heights(), **member_facts})
    manifest = {"what": "Seg2PoseNet models for `s2p demo` (seg2pose/training/demo_models.py)",
                "protocol": PROTOCOL, "classes": first.class_names,
                "cameras_fingerprint": first.cameras_fingerprint(), "weights": "float16",
                **facts, "members": listed}
    atomic_write_text(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")
    return written + [out / MANIFEST]


def remake(root: Path, out: Path = SHIPPED, seeds=TRAIN_SEEDS, threads: int = 1,
           log=print) -> list[Path]:
    """Make the shipped models again: per seed, synth the training scene under ``root``,
    bisect its default heights and train one quick-protocol model per class (one ``s2p
    train`` process per class, in parallel, ``threads`` each); then ``ship`` them into
    ``out``. Finished steps are skipped, so an interrupted remake resumes."""
    root = Path(root)

    def s2p_command(*args) -> list[str]:  # `s2p ARGS` with this interpreter, so this checkout's code
        return [sys.executable, "-c", "from seg2pose.cli import main; main()", *map(str, args)]

    root.mkdir(parents=True, exist_ok=True)

    def run(*argv) -> None:
        log("$ s2p " + " ".join(map(str, argv)))
        if subprocess.run(s2p_command(*argv)).returncode:
            raise S2PError(f"s2p {argv[0]} failed")

    members = []
    for seed in seeds:
        scene_dir = root / f"{TRAIN_PRESET}-seed{seed}"
        models = scene_dir / "models-quick"
        if not (scene_dir / "scene.json").exists():
            run("synth", "-o", scene_dir, "--preset", TRAIN_PRESET, "--seed", seed, "--no-progress")
            run("heights", scene_dir)
        scene = load_scene(scene_dir)
        t0 = time.perf_counter()
        procs = []
        for cls in scene.class_names:  # one process per class: both cores, and resumable
            argv = ["train", scene_dir, "--protocol", PROTOCOL, "--class", cls,
                    "--threads", threads, "-o", models]
            log("$ s2p " + " ".join(map(str, argv)) + " &")
            procs.append(subprocess.Popen(s2p_command(*argv), stdout=subprocess.DEVNULL))
        if any(p.wait() for p in procs):
            raise S2PError(f"training failed; run again to resume (models in {models})")
        members.append((models, scene, {"train_s": round(time.perf_counter() - t0),
                                        "threads_per_class": threads}))
    command = ("PYTHONPATH=. python -m seg2pose.training.demo_models ROOT "
               + " ".join(f"--seed {s}" for s in seeds) + f" --threads {threads}")
    return ship(members, Path(out), {"command": command})


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="Make the Seg2PoseNet models `s2p demo` ships.")
    p.add_argument("root", type=Path, help="work folder for the training scenes and their models")
    p.add_argument("--seed", type=int, action="append",
                   help=f"seed of a bench-preset training scene (repeatable; default: "
                        f"{' '.join(map(str, TRAIN_SEEDS))})")
    p.add_argument("--threads", type=int, default=1, help="torch threads per class process")
    p.add_argument("-o", "--out", type=Path, default=SHIPPED, help="where the shipped files go")
    a = p.parse_args(argv)
    for f in remake(a.root, a.out, tuple(a.seed or TRAIN_SEEDS), a.threads):
        print(f"wrote {f} ({f.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
