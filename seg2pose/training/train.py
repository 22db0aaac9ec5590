"""Training Seg2PoseNet (paper 4.1): the protocol, checkpoints and resuming.

The paper's protocol (``TrainConfig.paper()``, the default): one model per camera and class;
"best of four": four runs with the same four seeds for every camera, keeping the epoch with the
lowest validation loss over all runs; Adam, learning rate 5e-5, batch 16, 64 batches per epoch,
50 epochs; every fourth training example a rough-model example (3.5). Batches are drawn at
random (with replacement) from the training examples. The paper does not name its loss; the
default is the mean squared error of the normalised residual (residual / residual_scale, see
net.py). ``loss="euclid"`` (the mean Euclidean distance, i.e. the evaluation metric) was tried
on the CPU protocol and did worse on the test split (docs/RESULTS.md), so the presets keep MSE.

CPU presets: ``TrainConfig.quick()`` (lite-hr + mask geometry) and ``TrainConfig.demo()``
(lite) use a small arch, one run, a larger batch and learning rate with cosine decay, and **one
model for all lenses of the device** (``share_cameras``: the lenses sit centimetres apart, so
their examples are nearly the same views). ``quick`` keeps the paper's one model per class
(measured better than one model for all classes with a class input, ``share_classes``, which
``demo`` uses to train a single model). ``TrainConfig.long()`` is ``quick`` for 60 epochs with
a quarter of each batch rough: for a thousand or more annotated frames per split.

Checkpoints (``seg2pose.method.checkpoint``): ``MODELS/<camera>__<class>.safetensors`` (``__all`` when
shared). While training, ``<name>.state.pt`` holds the resume state (after every epoch); an
interrupted ``s2p train`` continues from it; a damaged one is set aside
(``.state.pt.damaged-<time>``) and training continues from the last good checkpoint. A NaN loss
stops training with a message; the best checkpoint so far stays on disk.

This module is the training loop (``train_model``, read it top to bottom) and the protocol;
the examples each model trains on are assembled by ``seg2pose.training.training_data``.
"""

from __future__ import annotations

import copy
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from seg2pose.core.clock import utc_stamp
from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.io.atomic import atomic_path, rename
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint
from seg2pose.method.features import GEO_VERSION, N_GEO
from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet, autocast, input_vector, pick_device
from seg2pose.method.ood import residual_limits
from seg2pose.training.config import TrainConfig, TrainSettings, same_protocol, training_record
from seg2pose.training.examples import ExampleSet
from seg2pose.training.train_fanout import fan_out
from seg2pose.training.training_data import camera_groups, films_rough, model_jobs
from seg2pose.training.zero_annotation import calibrate_radial

# ----------------------------------------------------------------------------------------------
# one model


@dataclass
class TrainData:
    """An example set with its network vectors precomputed."""

    ex: ExampleSet
    vec: np.ndarray  # (N, 4 + n_classes [+ n_geo]) float32
    y: np.ndarray    # (N, 2) float32 normalised target

    @classmethod
    def of(cls, ex: ExampleSet, norm: Normalisation, classes: list[str], shared: bool,
           geometry: bool = False) -> TrainData:
        cfg = NetConfig(n_classes=len(classes) if shared else 0, n_geo=N_GEO if geometry else 0)
        v = input_vector(cfg, norm, ex.centers, ex.normal, ex.cls, classes, ex.geo)
        return cls(ex, v, (ex.target / norm.residual_scale).astype(np.float32))

    def batch(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(crops (B, 1, S, S), vectors, targets) of the examples ``idx``."""
        return self.ex.crops_float(idx), self.vec[idx], self.y[idx]


def _loss(p: torch.Tensor, y: torch.Tensor, kind: str) -> torch.Tensor:
    """Training loss on normalised residuals (B, 2): half the mean squared error per
    coordinate ("mse"), or the mean Euclidean distance ("euclid", the evaluation metric up to
    the residual scale; robust to the heavy tail of occluded and merged masks)."""
    d2 = ((p.float() - y) ** 2).sum(dim=1)
    if kind == "euclid":
        return torch.sqrt(d2 + 1e-8).mean()
    if kind == "mse":
        return d2.mean() / 4
    raise S2PError(f"unknown loss {kind!r}; use 'mse' or 'euclid'")


def check_finite_loss(loss: float, where: str) -> None:
    if not math.isfinite(loss):
        raise S2PError(f"{where}: the loss became {loss}; training stopped "
                       "(the best checkpoint so far is kept). Try a lower learning rate.")


def _evaluate(net: Seg2PoseNet, data: TrainData, device, residual_scale: float, batch: int = 256,
              loss: str = "mse") -> tuple[float, float]:
    """(validation loss, mean Euclidean error in metres)."""
    net.eval()
    se = err = 0.0
    with torch.no_grad():
        for s in range(0, len(data.ex), batch):
            idx = np.arange(s, min(s + batch, len(data.ex)))
            x = torch.from_numpy(data.ex.crops_float(idx)).to(device)
            with autocast(device):
                p = net(x, torch.from_numpy(data.vec[idx]).to(device)).float().cpu().numpy()
            d = p - data.y[idx]
            se += float(np.sum(d * d))
            err += float(np.sum(np.linalg.norm(d, axis=1))) * residual_scale
    n = max(len(data.ex), 1)
    net.train()
    if loss == "euclid":
        return err / n / residual_scale, err / n
    return se / (4 * n), err / n


def evaluate_net(net: Seg2PoseNet, data: TrainData, device, residual_scale: float,
                 loss: str = "mse") -> tuple[float, float]:
    """(validation loss, mean Euclidean error in metres) of ``net`` on ``data`` (for loops
    beside this one, e.g. ``seg2pose.training.fine_tune``)."""
    return _evaluate(net, data, device, residual_scale, loss=loss)


def residual_loss(p: torch.Tensor, y: torch.Tensor, kind: str = "mse") -> torch.Tensor:
    """The training loss of predicted vs target normalised residuals (B, 2) (``_loss``)."""
    return _loss(p, y, kind)


def _lr_factor(schedule: str, steps: int):
    """Multiplier of the learning rate at step k: constant, or a cosine decay to 5 %."""
    if schedule == "cosine":
        return lambda k: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(k, steps) / steps))
    return lambda k: 1.0


_RESUME_KEYS = {"run", "epoch", "best", "best_state", "net", "scene_fingerprint", "config"}


def _set_aside(state_path: Path, err: Exception, ckpt: Checkpoint, cfg: TrainConfig,
               path: Path | None) -> dict | None:
    """Move a damaged resume state out of the way (``.state.pt.damaged-<time>``) and return a
    resume state rebuilt from the last good checkpoint (weights and best so far; the
    optimiser starts afresh), or None to train from the start."""
    stamp = utc_stamp()
    bad = state_path.with_name(f"{state_path.name}.damaged-{stamp}")
    rename(state_path, bad)
    why = f"{type(err).__name__}: {(str(err).splitlines() or [''])[0][:100]}"
    last = None
    if path is not None and path.exists():
        try:
            last = Checkpoint.load(path)
        except S2PError:
            last = None
    info = last.info if last is not None else {}
    if last is None or path is None or not (
            info.get("complete") is False and last.scene_fingerprint == ckpt.scene_fingerprint
            and isinstance(info.get("run"), int) and isinstance(info.get("epoch"), int)
            and same_protocol(info.get("train_config", asdict(cfg)), cfg)):
        say(f"the resume state {state_path} is damaged ({why}); set aside as {bad.name}; "
            "no checkpoint of this training to continue from, so it starts afresh", "warning")
        return None
    r, e = info["run"], info["epoch"]  # 1-based run, epochs done in it, of the best checkpoint
    weights = {k: v.detach().cpu() for k, v in last.net.state_dict().items()}
    best = {k: info[k] for k in ("val_loss", "val_error_m", "epoch", "seed", "run", "train_loss")
            if k in info}
    say(f"the resume state {state_path} is damaged ({why}); set aside as {bad.name}; "
        f"continuing from the last good checkpoint {path.name} (run {r}, epoch {e})", "warning")
    done = e >= cfg.epochs
    return {"run": r if done else r - 1, "epoch": 0 if done else e, "best": best,
            "best_state": weights, "net": weights}


def _load_resume(state_path: Path, ckpt: Checkpoint, cfg: TrainConfig, path: Path,
                 force: bool = False) -> dict | None:
    """The resume state of an interrupted training of the same scene and protocol, or None; a
    damaged one is set aside and rebuilt from the last good checkpoint (``_set_aside``; it has
    no optimiser state then)."""
    if not state_path.exists() or force:
        return None
    try:
        resume = torch.load(state_path, map_location="cpu", weights_only=False)
        if not isinstance(resume, dict) or not _RESUME_KEYS <= resume.keys():
            raise ValueError("not an s2p resume state")
    except Exception as e:  # noqa: BLE001 - torch and pickle raise many kinds on a damaged file
        return _set_aside(state_path, e, ckpt, cfg, path)
    if "opt" not in resume:
        return resume
    if resume.get("scene_fingerprint") != ckpt.scene_fingerprint or not same_protocol(resume.get("config"), cfg):
        say(f"{state_path} is from another scene or protocol; starting afresh", "warning")
        return None
    say(f"resuming {state_path.name[:-len('.state.pt')]} at run {resume['run'] + 1}, "
        f"epoch {resume['epoch'] + 1}")
    return resume


def train_model(train: TrainData | None, rough: TrainData | None, val: TrainData, net_cfg: NetConfig,
                cfg: TrainConfig, ckpt: Checkpoint, path: Path, progress: bool = True,
                runs: list[int] | None = None, settings: TrainSettings = TrainSettings(),
                init: dict | None = None) -> dict:
    """Best-of-``cfg.runs`` training of one model; writes ``path`` (+ .json) whenever the
    validation loss improves and keeps a resume state beside it. Returns the best info.
    ``init``: a state dict every run starts from (fine-tuning, e.g. self-training), instead of
    the seed's fresh network.
    ``runs``: only these runs (0-based; default all), e.g. one run per task when the runs are
    fanned out (seg2pose/training/train_fanout.py): runs are independent, each seeded by its number."""
    device = pick_device(settings.device)
    if device.type == "cpu":
        torch.set_num_threads(max(1, settings.threads))
    state_path = path.with_name(path.name + ".state.pt")
    # batch composition: n_real annotated + n_rough rough-model examples
    n_rough = 0
    if rough is not None and len(rough.ex):
        n_rough = cfg.batch_size if (train is None or not len(train.ex)) else (
            cfg.batch_size // cfg.rough_every if cfg.rough_every else 0)
    n_real = cfg.batch_size - n_rough
    if n_real and (train is None or not len(train.ex)):
        raise S2PError(f"{path.stem}: no training examples")
    # (examples, how many per batch) of the pools a batch draws from
    pools = [(d, k) for d, k in ((train, n_real), (rough, n_rough)) if k and d is not None]
    resume = _load_resume(state_path, ckpt, cfg, path, settings.force)
    start_run, start_epoch, best = (resume["run"], resume["epoch"], resume["best"]) if resume else (
        0, 0, {"val_loss": math.inf})
    best_state = resume["best_state"] if resume else None
    steps = cfg.epochs * cfg.batches_per_epoch
    for run in [r for r in (range(cfg.runs) if runs is None else runs) if r >= start_run]:
        # a run: a fresh network from its seed (or the resume state of an interrupted one)
        seed = cfg.seed + run
        torch.manual_seed(seed)
        net = Seg2PoseNet(net_cfg)
        if init is not None:
            net.load_state_dict(init)
        net = net.to(device)
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, _lr_factor(cfg.lr_schedule, steps))
        rng = np.random.default_rng(seed)
        epoch0 = 0
        if resume is not None and run == start_run and start_epoch > 0:
            net.load_state_dict(resume["net"])
            if "opt" in resume:  # not when rebuilt from a checkpoint (see _set_aside)
                opt.load_state_dict(resume["opt"])
                sched.load_state_dict(resume["sched"])
                rng.bit_generator.state = resume["rng"]
                torch.set_rng_state(resume["torch_rng"])
            epoch0 = start_epoch
        net.train()
        bar = tqdm(range(epoch0, cfg.epochs), desc=f"{path.stem} run {run + 1}/{cfg.runs}",
                   unit="epoch", disable=not progress, leave=False, file=sys.stderr)
        for epoch in bar:
            # an epoch: batches drawn at random (with replacement), one Adam step each
            tot = 0.0
            for _ in range(cfg.batches_per_epoch):
                parts = [data.batch(rng.integers(0, len(data.ex), k)) for data, k in pools]
                x, v, y = (torch.from_numpy(np.concatenate(p)).to(device) for p in zip(*parts))
                with autocast(device):
                    p = net(x, v)
                loss = _loss(p, y, cfg.loss)
                lv = float(loss.detach())
                check_finite_loss(lv, f"{path.stem} run {run + 1} epoch {epoch + 1}"
                                  + (f"; best checkpoint kept at {path}" if path.exists() else ""))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                sched.step()
                tot += lv
            # validation; the best epoch over all runs becomes the checkpoint
            val_loss, val_err = _evaluate(net, val, device, cfg.residual_scale, loss=cfg.loss)
            check_finite_loss(val_loss, f"{path.stem} run {run + 1} epoch {epoch + 1} (validation)")
            bar.set_postfix(loss=f"{tot / cfg.batches_per_epoch:.4f}", val=f"{val_loss:.4f}",
                            val_m=f"{val_err:.3f}")
            if val_loss < best["val_loss"]:
                best = {"val_loss": val_loss, "val_error_m": val_err, "epoch": epoch + 1,
                        "seed": seed, "run": run + 1, "train_loss": tot / cfg.batches_per_epoch}
                best_state = copy.deepcopy({k: t.detach().cpu() for k, t in net.state_dict().items()})
                ckpt.net.load_state_dict(best_state)
                ckpt.info = {**ckpt.info, **best, "complete": False}
                ckpt.save(path)
            # the resume state after every epoch (an interrupted training continues here)
            with atomic_path(state_path) as tmp:
                torch.save({"run": run if epoch + 1 < cfg.epochs else run + 1,
                            "epoch": epoch + 1 if epoch + 1 < cfg.epochs else 0,
                            "best": best, "best_state": best_state, "net": net.state_dict(),
                            "opt": opt.state_dict(), "sched": sched.state_dict(),
                            "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                            "scene_fingerprint": ckpt.scene_fingerprint,
                            "config": training_record(cfg, settings)},
                           tmp)
            if epoch + 1 == cfg.epochs:
                resume = None  # the next run starts fresh
        bar.close()
        say(f"{path.stem} run {run + 1}/{cfg.runs}: best so far val loss {best['val_loss']:.4f} "
            f"({best.get('val_error_m', float('nan')):.3f} m) at run {best.get('run')}, "
            f"epoch {best.get('epoch')}")
    if best_state is None:
        raise S2PError(f"{path.stem}: training produced no checkpoint")
    ckpt.net.load_state_dict(best_state)
    ckpt.info = {**ckpt.info, **best, "complete": True}
    ckpt.save(path)
    state_path.unlink(missing_ok=True)
    return best


# ----------------------------------------------------------------------------------------------
# a scene


def new_checkpoint(scene: Scene, job, cfg: TrainConfig, settings: TrainSettings, net_cfg: NetConfig,
                   all_classes: list[str], seen: ExampleSet) -> Checkpoint:
    """The checkpoint a model job trains into (a fresh network; the info says how it is
    trained). ``seen``: the examples it trains on (their residuals bound the far-residual
    check, ``seg2pose.method.ood``)."""
    n_rough = 0 if job.rough is None else len(job.rough)
    return Checkpoint(net=Seg2PoseNet(net_cfg), norm=job.norm, camera=job.camera, cls=job.key,
                      scene_fingerprint=scene.fingerprint(),
                      classes=all_classes if job.key == "*" else [],
                      info={"zero_annotation": cfg.zero_annotation, "cameras": job.cameras,
                            "train_config": training_record(cfg, settings), "n_train": len(job.train),
                            "geometry": GEO_VERSION if cfg.geometry else None,
                            "n_rough": n_rough, "n_val": len(job.val),
                            "residual_limit": residual_limits(seen.target, seen.cls)})


def train_scene(scene: Scene, out_models_dir: str | Path | None = None,
                config: TrainConfig | None = None, cameras: list[str] | None = None,
                classes: list[str] | None = None, progress: bool = True,
                map_groups=None, settings: TrainSettings | None = None) -> Path:
    """Train Seg2PoseNet models for a scene's cameras and classes; returns the model folder.

    ``map_groups(fn, items)``: given (e.g. ``seg2pose.core.ray.ray_map``), the camera
    groups' examples and then every camera x class x run are tasks of it
    (seg2pose/training/train_fanout.py), with the same checkpoints as the default, one model after
    another.

    ``settings``: device, threads, force (``TrainSettings()`` by default). Finished models
    (metadata "complete") are kept unless ``settings.force``; interrupted ones resume, also
    with other settings (only the protocol, ``config``, must be the same). Without ground truth
    only ``zero_annotation`` training is possible."""
    cfg = config or TrainConfig()
    settings = settings or TrainSettings()
    out = Path(out_models_dir) if out_models_dir else scene.root / "models"
    if cfg.self_train:
        raise S2PError("self-training (--self-train) is trained by "
                       "seg2pose.training.self_training.train_self_trained, not train_scene")
    if not cfg.zero_annotation and not scene.gt_path.exists():
        raise S2PError(f"{scene.root} has no ground truth ({scene.gt_path}); annotate it, or train "
                       "zero-annotation (from rough models only)")
    cams = cameras or list(scene.cameras)
    unknown = [c for c in cams if c not in scene.cameras]
    if unknown:
        raise S2PError(f"unknown cameras {unknown}; the scene has {list(scene.cameras)}")
    all_classes = scene.class_names
    cls_list = classes or all_classes
    bad = [c for c in cls_list if c not in all_classes]
    if bad:
        raise S2PError(f"unknown classes {bad}; the scene has {all_classes}")
    net_cfg = NetConfig.named(cfg.arch, len(all_classes) if cfg.share_classes else 0,
                              N_GEO if cfg.geometry else 0)
    gt = None if cfg.zero_annotation else read_poses(scene.gt_path, all_classes)
    if gt is not None:
        gt = gt.take(np.argsort(gt.frame, kind="stable"))
    out.mkdir(parents=True, exist_ok=True)
    def train_job(job, runs: list[int] | None = None, path: Path | None = None) -> dict:
        n_rough = 0 if job.rough is None else len(job.rough)
        seen = ExampleSet.concat([e for e in (job.train, job.rough) if e is not None
                                  and not (cfg.zero_annotation and e is job.train)])
        say(f"{job.path.stem}: {len(job.train)} annotated + {n_rough} rough training examples, "
            f"{len(job.val)} validation")
        ck = new_checkpoint(scene, job, cfg, settings, net_cfg, all_classes, seen)

        def data(ex: ExampleSet) -> TrainData:
            return TrainData.of(ex, job.norm, all_classes, job.key == "*", cfg.geometry)

        best = train_model(None if cfg.zero_annotation else data(job.train),
                           None if job.rough is None else data(job.rough), data(job.val), net_cfg,
                           cfg, ck, path or job.path, progress, runs, settings)
        if runs is None:
            finish_job(job)
        return best

    def finish_job(job) -> None:
        # filmed rough models carry the video's artefacts: the calibration's premise (real
        # masks have no radial bias the rough ones lack) made them worse (docs/RESULTS.md)
        if cfg.zero_annotation and cfg.radial_calibration and not all(
                films_rough(scene, c, cfg) for c in job.cameras):
            off = calibrate_radial(scene, job.path, "train" if "train" in scene.splits else None,
                                   center_method=cfg.center_method)
            say(f"{job.path.stem}: radial calibration from unlabelled masks (m): "
                + ", ".join(f"{k} {v:+.3f}" for k, v in off.items()))

    def group_jobs(group: tuple[str, list[str]]) -> list:
        # one camera group's models: independent of the other groups (own example random
        # stream, torch seeded per run), so groups may run in any order or in parallel
        return list(model_jobs(scene, out, cfg, net_cfg, group, cls_list, gt, settings.force))

    groups = camera_groups(scene, cams, cfg.share_cameras)
    if map_groups is None:
        for group in groups:
            for job in model_jobs(scene, out, cfg, net_cfg, group, cls_list, gt, settings.force):
                train_job(job)
    else:  # camera x class x run as tasks, the best run picked as above (same models)
        fan_out(map_groups, groups, group_jobs, train_job, finish_job, cfg, scene.fingerprint(),
                settings.force)
    return out
