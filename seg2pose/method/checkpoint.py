"""Trained Seg2PoseNet models as files, and their use on masks.

A checkpoint is ``MODELS/<camera>__<class>.safetensors`` (weights, with the metadata embedded
in the safetensors header) + a ``.json`` sidecar of the same metadata: camera, class, arch,
network configuration, input normalisation, scene fingerprint, and training facts (val loss,
epoch, seed, run, "complete"); a model made for a camera device rather than one scene (the
demo's shipped ones) also carries "cameras_fingerprint". ``all`` stands for a model serving all
cameras of a device or all classes (with a class one-hot input).

``Checkpoint.predict`` gives residuals for crops; ``predict_residuals`` for masks (crops cut
straight from the RLE runs, mask-geometry features when the model uses them); a ``ModelSet``
holds the models a run uses, per (camera, class), and an ``Ensemble`` averages several
folders' models (model averaging).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from seg2pose.core.errors import InputError, S2PError
from seg2pose.core.say import say
from seg2pose.io.atomic import atomic_path, atomic_write_text
from seg2pose.io.scene import Scene
from seg2pose.method import sparse as sparse_inference
from seg2pose.method.features import scene_geometry
from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet, autocast, input_vector, pick_device
from seg2pose.structures.masks import center_cut, crop_runs, downsample_crops

CHECKPOINT_VERSION = 1


CHECKPOINT_VERSION = 1


@dataclass
class Checkpoint:
    """A trained model with everything needed to use it: the arch, the normalisation, and
    which camera/class/scene it belongs to. ``cls`` is a class name or '*' (all classes, with
    a class one-hot input; ``classes`` lists their order)."""

    net: Seg2PoseNet
    norm: Normalisation
    camera: str
    cls: str
    scene_fingerprint: str = ""
    classes: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)   # val_loss, epoch, seed, run, ...

    def metadata(self) -> dict:
        return {"version": CHECKPOINT_VERSION, "camera": self.camera, "class": self.cls,
                "classes": self.classes, "arch": self.net.cfg.arch,
                "net": self.net.cfg.to_dict(), "normalisation": self.norm.to_dict(),
                "scene_fingerprint": self.scene_fingerprint, **self.info}

    def save(self, path: str | Path) -> None:
        """Write ``path`` (.safetensors) and its ``.json`` sidecar, both atomically."""
        from safetensors.torch import save_file

        path = Path(path)
        meta = self.metadata()
        state = {k: v.detach().float().cpu().contiguous() for k, v in self.net.state_dict().items()}
        with atomic_path(path) as tmp:
            save_file(state, str(tmp), metadata={"s2p": json.dumps(meta)})
        atomic_write_text(path.with_suffix(".json"), json.dumps(meta, indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path, *, arch: str | None = None, camera: str | None = None,
             device: str | torch.device = "cpu") -> Checkpoint:
        """Load a checkpoint; ``arch`` / ``camera``, when given, must match its metadata."""
        from safetensors import safe_open
        from safetensors.torch import load_file

        path = Path(path)
        if not path.exists():
            raise InputError("checkpoint not found", file=path)
        try:
            with safe_open(str(path), framework="pt") as f:
                meta = json.loads((f.metadata() or {}).get("s2p", "null"))
            state = load_file(str(path))
        except Exception as e:  # safetensors raises its own error types for corrupt files
            raise InputError(f"not a readable safetensors file ({e})", file=path) from None
        if not isinstance(meta, dict) or "net" not in meta:
            raise InputError("no s2p metadata in this safetensors file", file=path)
        if arch is not None and meta.get("arch") != arch:
            raise InputError(f"checkpoint is arch {meta.get('arch')!r}, expected {arch!r}",
                             file=path, field="arch")
        if camera is not None and meta.get("camera") not in (camera, "*"):
            raise InputError(f"checkpoint is for camera {meta.get('camera')!r}, expected {camera!r}",
                             file=path, field="camera")
        cfg = NetConfig.from_dict(meta["net"])
        net = Seg2PoseNet(cfg)
        try:
            net.load_state_dict(state)
        except RuntimeError as e:
            raise InputError(f"weights do not fit arch {cfg.arch!r}: {str(e).splitlines()[0]}",
                             file=path) from None
        net.to(device).eval()
        known = {"version", "camera", "class", "classes", "arch", "net", "normalisation",
                 "scene_fingerprint"}
        return cls(net=net, norm=Normalisation.from_dict(meta["normalisation"]),
                   camera=meta["camera"], cls=meta["class"],
                   scene_fingerprint=meta.get("scene_fingerprint", ""),
                   classes=list(meta.get("classes") or []),
                   info={k: v for k, v in meta.items() if k not in known})

    # ---- inference ----------------------------------------------------------------------------
    @torch.no_grad()
    def predict(self, crops: np.ndarray, centers: np.ndarray, normal_xy: np.ndarray,
                class_names: np.ndarray | None = None, batch: int = 64,
                device: torch.device | None = None, origin_xy: np.ndarray | None = None,
                geo: np.ndarray | None = None, sparse: bool | None = None) -> np.ndarray:
        """Residuals (N, 2) metres for full-resolution crops (N, S, S) uint8 (S >= the model's
        crop, usually the pipeline's 420; larger crops are cut around their centre), crop
        centres (N, 2) pixels and normal positions (N, 2) metres. ``origin_xy`` (2,): the
        camera centre, needed to apply a radial calibration (``info["radial_offset"]``, per
        class, metres along the camera-to-road-user direction, subtracted). ``geo`` (N, n_geo):
        the masks' geometry features (``seg2pose.method.features``), required when the net uses them.
        ``sparse``: exact sparse inference (``seg2pose.method.sparse``; default: on the CPU)."""
        device = device or next(self.net.parameters()).device
        vec = input_vector(self.net.cfg, self.norm, centers, normal_xy, class_names, self.classes,
                           geo)
        out = np.zeros((len(crops), 2), np.float32)
        self.net.eval()
        if sparse_inference.use_sparse(device, sparse):
            x = downsample_crops(center_cut(crops, self.net.cfg.crop), self.net.cfg.downsample)
            out = sparse_inference.predict_inputs(self.net, x, vec, batch, device)
        else:
            for s in range(0, len(crops), batch):
                x = torch.from_numpy(downsample_crops(center_cut(crops[s:s + batch], self.net.cfg.crop),
                                                      self.net.cfg.downsample))
                with autocast(device):
                    y = self.net(x[:, None].to(device), torch.from_numpy(vec[s:s + batch]).to(device))
                out[s:s + batch] = y.float().cpu().numpy()
        out = out * self.norm.residual_scale
        offsets = self.info.get("radial_offset") or {}
        if offsets and origin_xy is not None and len(out):
            names = np.asarray(class_names if class_names is not None else [self.cls] * len(out))
            out = out - radial_correction(offsets, names, normal_xy, origin_xy)
        return out


def radial_correction(offsets: dict[str, float], class_names: np.ndarray, normal_xy: np.ndarray,
                      origin_xy: np.ndarray) -> np.ndarray:
    """(N, 2) metres: per class, ``offsets[class]`` along the direction from the camera centre
    ``origin_xy`` (2,) to the normal positions (N, 2) (a zero-annotation model's radial bias,
    measured by ``seg2pose.training.zero_annotation.calibrate_radial``, to be subtracted)."""
    u = np.asarray(normal_xy, float) - np.asarray(origin_xy, float)[:2]
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
    off = np.array([offsets.get(str(c), 0.0) for c in class_names])
    return off[:, None] * u


def model_filename(camera: str, cls: str) -> str:
    """``<camera>__<class>.safetensors``; ``all`` in place of the camera or the class for a
    model serving all cameras (of one device) or all classes."""
    return f"{'all' if camera == '*' else camera}__{'all' if cls == '*' else cls}.safetensors"


# a class whose fine-tuning chose the baseline (``seg2pose.training.fine_tune_choice``): this
# file in place of its model makes ``s2p run`` use its normal positions
BASELINE_SUFFIX = ".baseline.json"


def baseline_marker_name(camera: str, cls: str) -> str:
    """``<camera>__<class>.baseline.json`` (``all`` for a model of every camera or class)."""
    return model_filename(camera, cls).removesuffix(".safetensors") + BASELINE_SUFFIX


@dataclass(eq=False)
class Ensemble:
    """Checkpoints from several model folders for one (camera, class): their residuals are
    averaged (model averaging; e.g. an annotated and a zero-annotation model, or runs with
    other seeds). ``info`` is the first member's."""

    members: tuple[Checkpoint, ...]

    @property
    def info(self) -> dict:
        return self.members[0].info


@dataclass
class ModelSet:
    """The checkpoints a run uses, looked up by (camera, class name): a Checkpoint each, or an
    Ensemble when several model folders are given."""

    models: dict[tuple[str, str], Checkpoint | Ensemble] = field(default_factory=dict)
    paths: dict[tuple[str, str], Path | list[Path]] = field(default_factory=dict)
    # (camera, class) pairs without a model, run with the baseline (``missing="baseline"``)
    fallback: list[tuple[str, str]] = field(default_factory=list)
    # those of them whose model folder chose the baseline (a ``BASELINE_SUFFIX`` marker)
    chosen_baseline: list[tuple[str, str]] = field(default_factory=list)

    @classmethod
    def load(cls, models_dir: Path | list[Path], cameras: list[str], classes: list[str],
             arch: str | None = None, fingerprint: str | None = None, device=None,
             allow_incomplete: bool = False, cameras_fingerprint: str | None = None,
             missing: str = "refuse") -> ModelSet:
        """The models of one folder, or of several folders as ensembles (residuals averaged).
        A camera and class without a model is refused (``missing="refuse"``), or with
        ``missing="baseline"`` left to the baseline (normal positions) and listed in
        ``fallback`` (a partial annotation trains models for some classes only).
        A marker ``<camera>__<class>.baseline.json`` met in the lookup before a model (a
        fine-tuning that found the baseline better for that class) runs the baseline there,
        whatever ``missing`` says, listed in ``fallback`` and ``chosen_baseline``, said once.
        A checkpoint whose training did not finish (metadata "complete": false) is refused
        unless ``allow_incomplete``. ``fingerprint`` / ``cameras_fingerprint``: the scene's
        (``Scene.fingerprint`` / ``Scene.cameras_fingerprint``); a checkpoint made for a scene
        is warned about on another scene, one made for a device (metadata
        "cameras_fingerprint") on other cameras."""
        if isinstance(models_dir, (list, tuple)):
            if len(models_dir) == 1:
                return cls.load(models_dir[0], cameras, classes, arch, fingerprint, device,
                                allow_incomplete, cameras_fingerprint, missing)
            sets = [cls.load(d, cameras, classes, arch, fingerprint, device, allow_incomplete,
                             cameras_fingerprint, missing) for d in models_dir]
            ms = cls()
            made: dict[tuple[int, ...], Ensemble] = {}
            # a pair missing from any folder falls back (only with missing="baseline")
            ms.fallback = sorted({k for s in sets for k in s.fallback})
            ms.chosen_baseline = sorted({k for s in sets for k in s.chosen_baseline})
            for key in sets[0].models:
                if key in ms.fallback:
                    continue
                members: list[Checkpoint] = []
                paths: list[Path] = []
                for s in sets:  # each set is one folder's: a Checkpoint and its Path per pair
                    ck, path = s.models[key], s.paths[key]
                    assert isinstance(ck, Checkpoint) and isinstance(path, Path)
                    members.append(ck)
                    paths.append(path)
                ids = tuple(map(id, members))  # one Ensemble per distinct member set (shared models)
                ms.models[key] = made.setdefault(ids, Ensemble(tuple(members)))
                ms.paths[key] = paths
            return ms
        models_dir = Path(models_dir)
        ms = cls()
        absent: list[tuple[str, str]] = []
        cache: dict[Path, Checkpoint] = {}
        markers_said: set[Path] = set()
        for cam in cameras:
            for c in classes:
                for name in (model_filename(cam, c), model_filename(cam, "*"),
                             model_filename("*", c), model_filename("*", "*")):
                    p = models_dir / name
                    marker = p.with_name(name.removesuffix(".safetensors") + BASELINE_SUFFIX)
                    if marker.exists():
                        ms.chosen_baseline.append((cam, c))
                        if marker not in markers_said:
                            markers_said.add(marker)
                            say(f"{marker}: {c} runs the baseline (normal positions): "
                                f"{_marker_reason(marker)}", "note")
                        break
                    if p.exists():
                        if p not in cache:
                            cache[p] = Checkpoint.load(p, arch=arch, camera=cam, device=device or "cpu")
                            ck = cache[p]
                            if ck.info.get("complete") is False:
                                msg = (f"its training did not finish (epoch {ck.info.get('epoch')}, "
                                       f"val loss {ck.info.get('val_loss')})")
                                if not allow_incomplete:
                                    raise InputError(f"{msg}: finish it with `s2p train`, or allow "
                                                     "incomplete models to use it anyway",
                                                     file=p.with_suffix(".json"), field="complete")
                                say(f"{p}: {msg}; used because incomplete models are allowed",
                                    "warning")
                            device_fp = ck.info.get("cameras_fingerprint")
                            if device_fp:  # made for the device: any scene of its cameras
                                if cameras_fingerprint and device_fp != cameras_fingerprint:
                                    say(f"{p} was made for other cameras (fingerprint "
                                        f"{device_fp}, this scene's cameras "
                                        f"{cameras_fingerprint})", "warning")
                            elif fingerprint and ck.scene_fingerprint and ck.scene_fingerprint != fingerprint:
                                say(f"{p} was trained on another scene (fingerprint "
                                    f"{ck.scene_fingerprint}, this scene {fingerprint})", "warning")
                        ms.models[(cam, c)] = cache[p]
                        ms.paths[(cam, c)] = p
                        break
                else:
                    absent.append((cam, c))
        if missing not in ("refuse", "baseline"):
            raise InputError(f"unknown policy {missing!r} for missing models; use refuse or "
                             "baseline", field="missing")
        if absent and missing == "refuse":
            raise S2PError(f"no Seg2PoseNet model in {models_dir} for "
                           f"{', '.join(f'{a}/{b}' for a, b in absent)}; train models for them, "
                           "or run the baseline (normal positions only) for them")
        ms.fallback = absent + ms.chosen_baseline
        return ms


def _marker_reason(marker: Path) -> str:
    """The marker's ``why`` (one line), or what it is when it has none or cannot be read."""
    try:
        why = json.loads(marker.read_text()).get("why")
    except (OSError, ValueError, AttributeError):
        why = None
    return str(why) if why else "its fine-tuning found the baseline better for this class"


def predict_residuals(scene: Scene, cam: str, ck, rles: list[bytes], height: int, width: int,
                      uv: np.ndarray, normal_xy: np.ndarray, names: np.ndarray, batch: int = 64
                      ) -> np.ndarray:
    """Seg2PoseNet residuals (N, 2) metres of checkpoint ``ck`` for N masks of camera ``cam``
    with centres uv (N, 2) pixels, normal positions (N, 2) metres and class names (N,): crops
    straight from the RLE runs and, when the model uses them, the mask-geometry features;
    one batch of full-resolution crops at a time (bounded memory). An Ensemble gives the mean
    of its members' residuals."""
    if isinstance(ck, Ensemble):
        return np.mean([predict_residuals(scene, cam, m, rles, height, width, uv, normal_xy, names,
                                          batch) for m in ck.members], axis=0)

    out = np.zeros((len(rles), 2))
    center = scene.cameras[cam].center[:2]
    for s in range(0, len(rles), batch):
        sl = slice(s, s + batch)
        part = rles[sl]
        crops = crop_runs(part, height, width, uv[sl])
        geo = (scene_geometry(scene, cam, part, height, width, uv[sl], normal_xy[sl], names[sl])
               if ck.net.cfg.n_geo else None)
        out[sl] = ck.predict(crops, uv[sl], normal_xy[sl], names[sl], batch=batch,
                             origin_xy=center, geo=geo)
    return out


def predict_with_spread(scene: Scene, cam: str, ck, rles: list[bytes], height: int, width: int,
                        uv: np.ndarray, normal_xy: np.ndarray, names: np.ndarray, batch: int = 64
                        ) -> tuple[np.ndarray, np.ndarray]:
    """``predict_residuals`` and the spread of an Ensemble's members about their mean (N,)
    metres (root mean square distance; zeros for one checkpoint): a variance signal for the
    error bar (``seg2pose.method.uncertainty``)."""
    if not isinstance(ck, Ensemble):
        return (predict_residuals(scene, cam, ck, rles, height, width, uv, normal_xy, names, batch),
                np.zeros(len(rles)))
    each = np.stack([predict_residuals(scene, cam, m, rles, height, width, uv, normal_xy, names,
                                       batch) for m in ck.members])
    mean = each.mean(axis=0)
    return mean, np.sqrt(((each - mean) ** 2).sum(axis=2).mean(axis=0))


def model_dirs(scene: Scene, models_dir) -> list[Path]:
    """The model folder(s) a run uses: one path, a list of them (averaged), or None for
    SCENE/models."""
    dirs = models_dir if isinstance(models_dir, (list, tuple)) else [models_dir] if models_dir else []
    return [Path(d) for d in dirs] or [scene.root / "models"]


def load_models(scene: Scene, cams: list[str], models_dir=None, arch: str | None = None,
                device: str | None = None, allow_incomplete: bool = False,
                missing: str = "refuse") -> ModelSet:
    """The ModelSet of ``cams`` x the scene's classes from ``models_dir`` (see ``model_dirs``;
    ``missing``: see ``ModelSet.load``)."""
    return ModelSet.load(model_dirs(scene, models_dir), cams, scene.class_names, arch=arch,
                         fingerprint=scene.fingerprint(), device=pick_device(device),
                         allow_incomplete=allow_incomplete,
                         cameras_fingerprint=scene.cameras_fingerprint(), missing=missing)
