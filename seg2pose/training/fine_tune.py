"""Fine-tuning Seg2PoseNet from a start on a scene's own annotations
(``s2p train SCENE --from MODELS``): a few keyframes of the user's scene make a rough-only,
zero-annotation, shipped or other scene's model fit this scene in minutes on a CPU.

Per start model (``fine_tune_data.start_models``; one per class, or one for all classes):

1. examples of the annotated masks of its classes (``fine_tune_data``: weighted by where the
   row came from, keyframes above interpolated frames; the test split never used), split by
   road user (masks scored by their box IoU with the annotated road user, ``min_mask_iou``);
2. a pool of rough-model examples (3.5) of its cameras and classes: ``rough_every``-th of every
   batch, so the network keeps what it knew about road users nobody annotated (against
   forgetting);
3. Adam from the start's weights, batches drawn by weight, a cosine schedule;
4. by default (``choose``) per class the best of the baseline (normal positions), the start
   and the fine-tuned model on annotated road users it was not trained on
   (``fine_tune_choice``: k-fold by road user), then one fine-tuning on every annotated road
   user when the fine-tuned model won; a class that chose the baseline gets a marker that
   ``s2p run`` reads (normal positions there, one line). Without ``choose``: early stopping on
   held-out road users (from ``min_held_out_users`` of a class), the start itself counting as
   epoch 0, training stopped after ``patience`` epochs without a better one; with fewer it
   trains all epochs and keeps the last (said in one line).

A class without annotations keeps its start model (copied, marked so); nothing here is an error
at the end of a long run. The fine-tuned checkpoint records its start (file, sha256), the
examples per source and the held-out errors before and after (``info["fine_tune"]``).
"""

from __future__ import annotations

import copy
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from seg2pose.core.digest import file_sha256
from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.atomic_set import remove_path
from seg2pose.io.poses import read_poses
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint, baseline_marker_name
from seg2pose.method.net import autocast, input_vector, pick_device
from seg2pose.method.ood import residual_limits
from seg2pose.training.examples import ExampleSet, rough_examples
from seg2pose.training.fine_tune_choice import choose, cross_validate
from seg2pose.training.fine_tune_data import (
    Annotated,
    StartModel,
    WeightedExamples,
    annotated_masks,
    baseline_markers,
    held_out_road_users,
    split_by_road_user,
    start_models,
    usable_rows,
    weighted_examples,
)
from seg2pose.training.train import TrainData, check_finite_loss, evaluate_net, residual_loss


@dataclass(frozen=True)
class FineTuneOptions:
    """How long and how hard to fine-tune (defaults measured in benches/annotation_curve.py)."""

    epochs: int = 8
    batches_per_epoch: int = 16
    batch_size: int = 24
    lr: float = 3e-4
    rough_every: int = 4          # every 4th example of a batch rough (0: none)
    rough_per_class: int = 200    # rough-model pool per class (split over the cameras)
    patience: int = 3             # epochs without a better held-out error before stopping
    # hold out road users of a class only when it has this many annotated: with fewer, one
    # held-out road user is a third of the annotation and too few to judge an epoch by (on the
    # tuning scene early stopping on it kept the start in every class, the fixed schedule was
    # better in every class: docs/RESULTS.md, "Fine-tuning on a few keyframes"); the fixed
    # schedule then runs to its end and its last epoch is kept
    min_held_out_users: int = 5
    # per class keep the best of the baseline, the start and the fine-tuned model on held-out
    # road users (``fine_tune_choice``: k-fold by road user, then one fine-tuning on all); off:
    # the early stopping above
    choose: bool = True
    folds: int = 3
    baseline_min_users: int = 2  # a class takes the baseline only from this many road users
    # annotated masks whose box IoU with their road user's projected 3D box is below this
    # (merged, cut: fine_tune_data.truth_box_iou) are not trained on; 0: all are
    min_mask_iou: float = 0.0
    seed: int = 0
    threads: int = 2
    device: str | None = None
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("epochs", "batches_per_epoch", "batch_size", "patience", "threads", "folds"):
            if int(getattr(self, name)) < 1:
                raise S2PError(f"fine-tuning: {name} must be at least 1, got {getattr(self, name)}")


@dataclass
class FineTuneResult:
    """What became of each model: file name -> one line (trained, kept), and the wall time."""

    lines: dict[str, str]
    wall_s: float


def _data(sm: StartModel, ex: ExampleSet) -> TrainData:
    vec = input_vector(sm.ck.net.cfg, sm.ck.norm, ex.centers, ex.normal, ex.cls, sm.ck.classes, ex.geo)
    return TrainData(ex, vec, (ex.target / sm.ck.norm.residual_scale).astype(np.float32))


def train_from(sm: StartModel, train: WeightedExamples, rough: ExampleSet | None,
               val: ExampleSet | None, opts: FineTuneOptions) -> dict:
    """Fine-tune ``sm.ck.net`` in place (see the module docstring); returns the facts of the
    kept epoch: epoch (0: the start), val_error_m, start_val_error_m, epochs_run."""
    device = pick_device(opts.device)
    if device.type == "cpu":
        torch.set_num_threads(max(1, opts.threads))
    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    net = sm.ck.net.to(device)
    rs = sm.ck.norm.residual_scale
    tr = _data(sm, train.ex)
    p = train.weight / train.weight.sum()
    ro = _data(sm, rough) if rough is not None and len(rough) else None
    va = _data(sm, val) if val is not None and len(val) else None
    n_rough = opts.batch_size // opts.rough_every if (ro is not None and opts.rough_every) else 0
    n_real = opts.batch_size - n_rough
    opt = torch.optim.Adam(net.parameters(), lr=opts.lr)
    steps = opts.epochs * opts.batches_per_epoch
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda k: 0.05 + 0.95 * 0.5 * (1 + np.cos(np.pi * min(k, steps) / steps)))
    start_err = evaluate_net(net, va, device, rs)[1] if va is not None else float("nan")
    best = {"epoch": 0, "val_error_m": start_err}
    best_state = copy.deepcopy({k: t.detach().cpu() for k, t in net.state_dict().items()})
    since = 0
    net.train()
    bar = tqdm(range(opts.epochs), desc=f"fine-tune {sm.path.stem}", unit="epoch",
               disable=not opts.progress, leave=False, file=sys.stderr)
    epoch = 0
    for epoch in bar:
        for _ in range(opts.batches_per_epoch):
            parts = [tr.batch(rng.choice(len(p), n_real, p=p))]
            if n_rough:
                assert ro is not None  # n_rough is 0 without rough examples
                parts.append(ro.batch(rng.integers(0, len(ro.ex), n_rough)))
            x, v, y = (torch.from_numpy(np.concatenate(q)).to(device) for q in zip(*parts))
            with autocast(device):
                out = net(x, v)
            loss = residual_loss(out, y)
            check_finite_loss(float(loss.detach()), f"fine-tuning {sm.path.stem} epoch {epoch + 1}")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
        if va is None:  # nothing held out: the last epoch
            best = {"epoch": epoch + 1, "val_error_m": float("nan")}
            best_state = {k: t.detach().cpu().clone() for k, t in net.state_dict().items()}
            continue
        err = evaluate_net(net, va, device, rs)[1]
        bar.set_postfix(val_m=f"{err:.3f}", best=f"{best['val_error_m']:.3f}")
        if err < best["val_error_m"]:
            best = {"epoch": epoch + 1, "val_error_m": err}
            best_state = copy.deepcopy({k: t.detach().cpu() for k, t in net.state_dict().items()})
            since = 0
        else:
            since += 1
            if since >= opts.patience:
                break
    bar.close()
    net.load_state_dict(best_state)
    net.eval()
    return {**best, "start_val_error_m": start_err, "epochs_run": epoch + 1}


def _keep_start(sm: StartModel, out: Path, why: str) -> str:
    """Copy the start model into ``out`` unchanged (marked), for a model nothing can tune."""
    ck = Checkpoint.load(sm.path)
    ck.info["fine_tune"] = {"skipped": why, "start": {"file": str(sm.path),
                                                      "sha256": file_sha256(sm.path)}}
    ck.info["complete"] = True
    ck.save(out / sm.path.name)
    return f"{sm.path.stem}: kept its start model ({why})"


def _rough_pool(scene: Scene, sm: StartModel, opts: FineTuneOptions, center: str) -> ExampleSet | None:
    if not opts.rough_every or not opts.rough_per_class:
        return None
    crop, factor = sm.ck.net.cfg.crop, sm.ck.net.cfg.downsample
    rng = np.random.default_rng([opts.seed, sum(map(ord, sm.path.name))])
    n = max(1, opts.rough_per_class // len(sm.cameras))
    return ExampleSet.concat([rough_examples(scene, cam, c, n, rng, crop, factor, center)
                              for cam in sm.cameras for c in sm.classes])


def _save_tuned(scene: Scene, sm: StartModel, tr: WeightedExamples, va: WeightedExamples,
                rough: ExampleSet | None, facts: dict, out: Path, opts: FineTuneOptions,
                t0: float) -> None:
    """Write the fine-tuned ``sm`` into ``out`` with what it was made of (``info["fine_tune"]``)."""
    ck = sm.ck
    seen = ExampleSet.concat([e for e in (tr.ex, rough) if e is not None and len(e)])
    ck.info.pop("cameras_fingerprint", None)  # now made for this scene
    ck.scene_fingerprint = scene.fingerprint()
    ck.info.update({
        "complete": True, "n_train": len(tr.ex), "n_val": len(va.ex),
        "residual_limit": residual_limits(seen.target, seen.cls),
        "fine_tune": {"start": {"file": str(sm.path), "sha256": file_sha256(sm.path)},
                      "options": {k: getattr(opts, k) for k in ("epochs", "batches_per_epoch",
                                  "batch_size", "lr", "rough_every", "rough_per_class", "patience",
                                  "choose", "folds", "baseline_min_users", "min_mask_iou", "seed")},
                      "examples_by_weight": {str(k): int((tr.weight == k).sum())
                                             for k in np.unique(tr.weight)},
                      "road_users": {"train": np.unique(tr.road_user).tolist(),
                                     "val": np.unique(va.road_user).tolist()},
                      "wall_s": round(time.perf_counter() - t0, 1), **facts}})
    ck.save(out / sm.path.name)


def fine_tune_model(scene: Scene, sm: StartModel, ann: dict[str, Annotated], val_users: np.ndarray,
                    out: Path, opts: FineTuneOptions) -> str:
    """One start model fine-tuned on its classes' annotated masks into ``out`` (or kept when
    none of its classes is annotated); returns the line that says which."""
    crop, factor = sm.ck.net.cfg.crop, sm.ck.net.cfg.downsample
    center = (sm.ck.info.get("train_config") or {}).get("center_method", DEFAULT_CENTER_METHOD)
    offset = sm.ck.info.get("radial_offset") or None
    for c in sm.classes:  # an earlier fine-tuning's choice of the baseline (made again below)
        remove_path(out / baseline_marker_name(sm.camera, c))
    w = WeightedExamples.concat([weighted_examples(scene, a.take(np.flatnonzero(np.isin(a.cls, sm.classes))),
                                                   crop, factor, center, offset, opts.min_mask_iou)
                                 for cam, a in ann.items() if cam in sm.cameras], crop, factor)
    if not len(w.ex):
        return _keep_start(sm, out, f"no annotated {'/'.join(sm.classes)} masks")
    rough = _rough_pool(scene, sm, opts, center)
    if opts.choose:
        return _choose_and_train(scene, sm, w, rough, out, opts)
    tr, va = split_by_road_user(w, val_users)
    if not tr.weight.sum() > 0:
        tr, va = w, split_by_road_user(w, np.zeros(0, np.int64))[1]
    if not tr.weight.sum() > 0:
        return _keep_start(sm, out, f"every annotated mask's box IoU is below {opts.min_mask_iou}")
    n_users = len(np.unique(w.road_user))
    if not len(va.ex):
        say(f"{sm.path.stem}: {n_users} annotated road user(s), none to hold out; trains all "
            f"{opts.epochs} epochs without early stopping", "note")
    say(f"{sm.path.stem}: fine-tuning on {len(tr.ex)} annotated examples of "
        f"{len(np.unique(tr.road_user))} road users (+ {0 if rough is None else len(rough)} rough), "
        f"validating on {len(va.ex)} of {len(np.unique(va.road_user))} held-out road users")
    t0 = time.perf_counter()
    facts = train_from(sm, tr, rough, va.ex if len(va.ex) else None, opts)
    _save_tuned(scene, sm, tr, va, rough, facts, out, opts, t0)
    if facts["epoch"] == 0:
        return (f"{sm.path.stem}: no epoch beat the start model on the held-out road users "
                f"({facts['start_val_error_m']:.3f} m); kept the start's weights")
    held = (f"held-out error {facts['start_val_error_m']:.3f} -> {facts['val_error_m']:.3f} m"
            if np.isfinite(facts["val_error_m"]) else "nothing held out")
    return f"{sm.path.stem}: fine-tuned, epoch {facts['epoch']} of {facts['epochs_run']} run; {held}"


def _choose_and_train(scene: Scene, sm: StartModel, w: WeightedExamples, rough: ExampleSet | None,
                      out: Path, opts: FineTuneOptions) -> str:
    """Per class the best of baseline, start and fine-tuned on held-out road users
    (``fine_tune_choice``), then the network the classes keep (fine-tuned on every annotated
    road user, or the start) and a baseline marker per class that chose the baseline."""
    t0 = time.perf_counter()
    n_users = len(np.unique(w.road_user))
    say(f"{sm.path.stem}: choosing between the baseline, the start and a fine-tuning on "
        f"{len(w.ex)} annotated examples of {n_users} road user(s) "
        f"({min(opts.folds, n_users) if n_users > 1 else 0} folds by road user)")
    device = pick_device(opts.device)

    def train(s: StartModel, tr: WeightedExamples) -> None:
        if tr.weight.sum() > 0:  # else every mask of the fold is suspicious: the start stays
            train_from(s, tr, rough, None, opts)

    errors = cross_validate(sm, w, device, train, opts.folds, opts.seed)
    ch = choose(errors, w, sm.classes, opts.baseline_min_users)
    for c in sm.classes:
        marker = out / baseline_marker_name(sm.camera, c)
        if c in ch.baseline:
            atomic_write_text(marker, json.dumps({
                "why": f"on {ch.users[c]} annotated road user(s) held out, " + ch.describe(c),
                "scores_m": ch.scores[c], "start": str(sm.path)}, indent=1) + "\n")
    summary = "; ".join(ch.describe(c) for c in ch.scores)
    served = [c for c in sm.classes if c not in ch.baseline]
    if not served:  # every class of this model runs the baseline: no model file
        for p in (out / sm.path.name, (out / sm.path.name).with_suffix(".json")):
            remove_path(p)
        return f"{sm.path.stem}: baseline chosen ({summary})"
    if ch.net == "start" or not w.weight.sum() > 0:
        _keep_start(sm, out, f"the start beat fine-tuning on held-out road users ({summary})")
        return f"{sm.path.stem}: start chosen ({summary})"
    facts = train_from(sm, w, rough, None, opts)
    facts["choice"] = {c: {"chosen": ch.chosen(c), "users": ch.users[c], **ch.scores[c]} for c in ch.scores}
    _save_tuned(scene, sm, w, WeightedExamples.empty(crop=sm.ck.net.cfg.crop,
                                                      factor=sm.ck.net.cfg.downsample),
                rough, facts, out, opts, t0)
    return f"{sm.path.stem}: fine-tuned chosen ({summary})"


def fine_tune_scene(scene: Scene, start: str | Path, out: str | Path | None = None,
                    opts: FineTuneOptions | None = None, cameras: list[str] | None = None,
                    classes: list[str] | None = None) -> FineTuneResult:
    """``s2p train SCENE --from START``: every start model fitting the scene fine-tuned on the
    scene's annotations into ``out`` (default ``SCENE/models``); see the module docstring."""
    opts = opts or FineTuneOptions()
    t0 = time.perf_counter()
    start, out = Path(start), Path(out) if out else scene.root / "models"
    if out.resolve() == start.resolve():
        raise S2PError(f"{out}: fine-tuned models need another folder than the start models they "
                       "come from (the start stays as it is for the next fine-tuning)")
    if not scene.gt_path.exists():
        raise S2PError(f"{scene.root} has no annotations to fine-tune on ({scene.gt_path}); "
                       "annotate some keyframes first (s2p annotate)")
    cams = cameras or list(scene.cameras)
    cls_list = classes or scene.class_names
    starts = start_models(scene, start, cams, cls_list)
    kept = baseline_markers(start, cams, cls_list)
    gt = usable_rows(read_poses(scene.gt_path, scene.class_names), scene)
    gt = gt.take(np.argsort(gt.frame, kind="stable"))
    used = sorted({c for sm in starts for c in sm.cameras})
    ann = {cam: annotated_masks(scene, cam, gt) for cam in used}
    all_ann = [a for a in ann.values() if len(a.rles)]
    val_users = held_out_road_users(np.concatenate([a.road_user for a in all_ann]) if all_ann else
                                    np.zeros(0, np.int64),
                                    np.concatenate([a.cls for a in all_ann]) if all_ann else
                                    np.zeros(0, object), opts.seed, opts.min_held_out_users)
    out.mkdir(parents=True, exist_ok=True)
    lines = {}
    for sm in starts:
        lines[sm.path.name] = fine_tune_model(scene, sm, ann, val_users, out, opts)
        say(lines[sm.path.name])
    for marker in sorted(set(kept.values())):  # the start's choice of the baseline stands
        atomic_write_text(out / marker.name, marker.read_text())
        lines[marker.name] = f"{marker.name}: the start runs the baseline here; its marker is kept"
        say(lines[marker.name])
    return FineTuneResult(lines, time.perf_counter() - t0)
