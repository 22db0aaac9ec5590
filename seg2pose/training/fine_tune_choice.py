"""Never worse than what it replaces: per class, ``s2p train --from`` keeps whichever of the
baseline (normal positions), the start model and the fine-tuned model is best on the annotated
road users it was not trained on.

With a few keyframes a fine-tuning can make a class worse (two or three annotated cars), and a
start made for another device can be worse than the baseline before any annotation. Both are
measured on the scene's own annotations:

- the baseline and the start are not trained on the annotations: every annotated road user is
  held out for them, so their errors are measured on all of them;
- the fine-tuned model is cross-validated by road user (k-fold, ``k = min(folds, road users)``;
  with two road users leave-one-road-user-out): per fold a copy of the start is fine-tuned on
  the other road users with the same schedule as the final model and measured on the fold's.
  Frames of a road user the copy trained on never score it (they would measure memory, not
  generalisation).

A candidate's score is the mean over road users of each one's mean error (metres), so a long
annotated track does not outvote a short one. The lowest wins; on a tie the simpler one
(baseline, then start). A class with one annotated road user cannot validate a fine-tuning:
the baseline and the start are compared on it, and when the start wins it is fine-tuned
unvalidated (with one road user the fixed schedule beat keeping the start on the tuning scene:
docs/RESULTS.md, "Fine-tuning on a few keyframes"); the line says so. When the baseline wins on
that one road user the start is kept all the same: a switch to the baseline needs
``baseline_min_users`` (2) annotated road users of the class (on the measured scenes every
switch made on one road user left the class worse on the test split: RESULTS.md).

A class that chose the baseline gets a marker in the model folder, ``<camera>__<class>.baseline.json``
(``BASELINE_SUFFIX``, read by ``seg2pose.method.checkpoint.ModelSet.load``): ``s2p run`` uses
the normal positions for it and says so in one line.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from seg2pose.method.net import autocast, input_vector
from seg2pose.training.examples import ExampleSet
from seg2pose.training.fine_tune_data import StartModel, WeightedExamples

CANDIDATES = ("baseline", "start", "fine-tuned")  # simplest first: ties go to the earlier


def example_errors(sm: StartModel, ex: ExampleSet, device, batch: int = 256) -> np.ndarray:
    """Euclidean error (N,) metres of ``sm``'s network on the examples ``ex`` (prediction vs
    target, both in the start's frame: its radial offset is in the targets)."""
    net, rs = sm.ck.net.to(device), sm.ck.norm.residual_scale
    vec = input_vector(net.cfg, sm.ck.norm, ex.centers, ex.normal, ex.cls, sm.ck.classes, ex.geo)
    out = np.zeros(len(ex))
    was_training = net.training
    net.eval()
    with torch.no_grad():
        for s in range(0, len(ex), batch):
            idx = np.arange(s, min(s + batch, len(ex)))
            x = torch.from_numpy(ex.crops_float(idx)).to(device)
            with autocast(device):
                p = net(x, torch.from_numpy(vec[idx]).to(device)).float().cpu().numpy()
            out[idx] = np.linalg.norm(p * rs - ex.target[idx], axis=1)
    net.train(was_training)
    return out


def per_user_mean(err: np.ndarray, users: np.ndarray) -> float:
    """Mean over road users of each road user's mean of ``err`` (NaN errors left out; NaN when
    no road user has one)."""
    means = [float(np.nanmean(err[users == u])) for u in np.unique(users)
             if np.isfinite(err[users == u]).any()]
    return float(np.mean(means)) if means else float("nan")


def road_user_folds(users: np.ndarray, k: int, seed: int) -> list[np.ndarray]:
    """The distinct road users of ``users`` shuffled (seeded) and dealt into ``k`` folds of
    sizes differing by at most one (k clipped to the number of road users)."""
    u = np.random.default_rng(seed).permutation(np.unique(users))
    k = max(1, min(k, len(u)))
    return [u[i::k] for i in range(k)]


@dataclass
class Choice:
    """Scores (metres, per class and candidate; NaN: not measured), road users per class, the
    network kept for the classes that do not take the baseline ("start" or "fine-tuned"), the
    classes that take the baseline, whether a fine-tuning is unvalidated (one road user)."""

    scores: dict[str, dict[str, float]]
    users: dict[str, int]
    net: str = "start"
    baseline: list[str] = field(default_factory=list)
    unvalidated: list[str] = field(default_factory=list)

    def chosen(self, cls: str) -> str:
        return "baseline" if cls in self.baseline else self.net

    def describe(self, cls: str) -> str:
        s = self.scores[cls]
        shown = ", ".join(f"{c} {s[c]:.3f} m" for c in CANDIDATES if math.isfinite(s[c]))
        extra = "; fine-tuned unvalidated (one road user)" if cls in self.unvalidated else ""
        return f"{cls}: {self.chosen(cls)} ({self.users[cls]} road user(s): {shown}{extra})"


def cross_validate(sm: StartModel, w: WeightedExamples, device, train: Callable, folds: int,
                   seed: int) -> dict[str, np.ndarray]:
    """Per-example errors (N,) metres of each candidate on ``w``: baseline and start on every
    example, fine-tuned (``train(start_copy, examples)`` fine-tunes a copy in place) on each
    fold's road users from a copy trained on the other folds (NaN where no fold could train)."""
    out = {"baseline": w.baseline_error.astype(float), "start": example_errors(sm, w.ex, device),
           "fine-tuned": np.full(len(w.ex), np.nan)}
    if len(np.unique(w.road_user)) < 2:
        return out
    for held in road_user_folds(w.road_user, folds, seed):
        val = np.isin(w.road_user, held)
        fold = copy.deepcopy(sm)
        train(fold, w.take(np.flatnonzero(~val)))
        out["fine-tuned"][val] = example_errors(fold, w.ex.take(np.flatnonzero(val)), device)
    return out


def choose(errors: dict[str, np.ndarray], w: WeightedExamples, classes: list[str],
           baseline_min_users: int = 2) -> Choice:
    """The candidates' scores per class of ``classes`` (those with annotated examples) and the
    choice (see the module docstring). One network serves all of ``classes``: "fine-tuned"
    when its summed score over the classes where both were measured is lower than the
    start's; then each class with ``baseline_min_users`` or more annotated road users whose
    baseline beats that network takes the baseline (fewer: the network stays)."""
    scores, users = {}, {}
    for c in classes:
        sel = np.flatnonzero(w.ex.cls == c)
        if not len(sel):
            continue
        users[c] = len(np.unique(w.road_user[sel]))
        scores[c] = {k: per_user_mean(v[sel], w.road_user[sel]) for k, v in errors.items()}
    both = [c for c in scores if math.isfinite(scores[c]["fine-tuned"])]
    ch = Choice(scores, users)
    if both:
        ft = sum(scores[c]["fine-tuned"] for c in both)
        ch.net = "fine-tuned" if ft < sum(scores[c]["start"] for c in both) else "start"
    elif scores and any(scores[c]["start"] < scores[c]["baseline"] for c in scores):
        # one road user a class: nothing validates a fine-tuning; it runs where the start
        # already beats the baseline (module docstring)
        ch.net, ch.unvalidated = "fine-tuned", [c for c in scores if scores[c]["start"] < scores[c]["baseline"]]
    for c, s in scores.items():
        net_score = s["fine-tuned"] if ch.net == "fine-tuned" and c in both else s["start"]
        if not s["baseline"] > net_score and users[c] >= baseline_min_users:  # a tie: the baseline
            ch.baseline.append(c)
    return ch
