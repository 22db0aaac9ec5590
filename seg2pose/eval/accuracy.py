"""The accuracy benchmark's bookkeeping (issue 14): the nine configurations' error ratios
(Seg2PoseNet / baseline) over several scene seeds, with their spread, from the paper-table
results of each seed. The driver that runs the ``s2p`` steps is ``seg2pose.cli.accuracy``.

Folder layout under ROOT, per seed: ``<preset>-seed<N>/`` (the scene, written by ``s2p synth``),
``.../models-<variant>/`` and ``.../table-<variant>/results.json`` (``s2p paper-table``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.eval.paper_table import refuse_table
from seg2pose.io.atomic import atomic_write_text
from seg2pose.io.scene import load_scene

VARIANT_TITLES = {"s2pn": "Seg2PoseNet (annotated)", "s2pn-long": "annotated, long protocol",
                  "zero": "zero-annotation",
                  "zero-random": "zero, random rough", "zero-track": "zero + self (track)",
                  "zero-fused": "zero + self (fused)",
                  "zero-views": "zero + self (views)",
                  "zero-random-track": "random + self (track)",
                  "zero-random-views": "random + self (views)"}
CONFIGS = ["mono-1", "mono-2", "mono-3", "stereo-30", "stereo-40", "stereo-10",
           "tri-I", "tri-L", "tri-T"]


@dataclass
class SeedResult:
    """Mean errors (metres) of one scene seed: config -> {"baseline": e, variant: e}, and per
    class: config -> class -> {"baseline": e, variant: e}; training seconds per variant."""

    seed: int
    errors: dict = field(default_factory=dict)
    per_class: dict = field(default_factory=dict)
    train_s: dict = field(default_factory=dict)


SMOOTHED = "+smooth"  # suffix of the smoothed rows' names: "baseline+smooth", "s2pn+smooth"


def read_table(path: Path, variant: str, res: SeedResult, suffix: str = "") -> None:
    """Add one paper-table results.json to ``res`` (rows named baseline / ``variant``, each
    with ``suffix``)."""
    try:
        data = json.loads(Path(path).read_text())["results"]
    except (OSError, ValueError, KeyError) as e:
        raise S2PError(f"{path}: not a paper-table results.json ({e})") from None
    for key, r in data.items():
        cfg, method = key.split()
        name = ("baseline" if method == "baseline" else variant) + suffix
        res.errors.setdefault(cfg, {})[name] = float(r["mean_error"])
        for cls, e in (r.get("per_class") or {}).items():
            res.per_class.setdefault(cfg, {}).setdefault(cls, {})[name] = float(e)


def smoothed_results(scene_dir: Path, table: Path, smooth: int) -> Path:
    """TABLE/smooth<N>.json: the table's runs fused again with ``smooth`` (what
    ``s2p paper-table --smooth N`` gives, without running the network again); cached."""
    path = table / f"smooth{smooth}.json"
    if not path.exists():
        res = refuse_table(load_scene(scene_dir), table, smooth)
        atomic_write_text(path, json.dumps({"smooth_frames": smooth, "results": {
            k: r.to_dict() for k, r in res.items()}}, indent=1) + "\n")
    return path


def ratios(results: list[SeedResult], variant: str, cfg: str, base: str = "baseline") -> np.ndarray:
    """(n_seeds,) variant / ``base`` mean error of configuration ``cfg``."""
    return np.array([r.errors[cfg][variant] / r.errors[cfg][base] for r in results
                     if cfg in r.errors and variant in r.errors[cfg] and base in r.errors[cfg]])


def class_ratios(results: list[SeedResult], variant: str, cfg: str, cls: str,
                 base: str = "baseline") -> np.ndarray:
    return np.array([r.per_class[cfg][cls][variant] / r.per_class[cfg][cls][base]
                     for r in results if cls in r.per_class.get(cfg, {})
                     and variant in r.per_class[cfg][cls] and base in r.per_class[cfg][cls]])


def _ms(a: np.ndarray) -> str:
    """'mean (min-max)' of a few seeds' ratios."""
    if len(a) == 0:
        return "-"
    return f"{a.mean():.3f}x ({a.min():.2f}-{a.max():.2f})" if len(a) > 1 else f"{a[0]:.3f}x"


def columns(results: list[SeedResult], variants) -> list[tuple[str, str, str]]:
    """(title, variant row, baseline row) of the summary's ratio columns: each variant over
    the baseline; where smoothed rows exist, the smoothed variant over the plain baseline
    (the paper's) and over the baseline smoothed the same way (the fair comparison)."""
    cols = [(VARIANT_TITLES[v], v, "baseline") for v in variants]
    if any(k.endswith(SMOOTHED) for r in results for e in r.errors.values() for k in e):
        for v in variants:
            cols += [(f"{v}{SMOOTHED} / baseline", v + SMOOTHED, "baseline"),
                     (f"{v}{SMOOTHED} / baseline{SMOOTHED}", v + SMOOTHED, "baseline" + SMOOTHED)]
    return cols


def summary(results: list[SeedResult], variants=("s2pn", "zero")) -> str:
    """The nine configurations: baseline metres and each variant's ratio, mean (min-max)
    over the seeds; then per class for mono-1 and tri-I; then training time."""
    seeds = ", ".join(str(r.seed) for r in results)
    cols = columns(results, variants)
    lines = [f"seeds {seeds}: mean error ratio to the baseline, mean (min-max) over seeds",
             f"{'config':<10} {'baseline m':>11} " + " ".join(f"{t:>26}" for t, _, _ in cols)]
    for cfg in CONFIGS:
        base = np.array([r.errors[cfg]["baseline"] for r in results if cfg in r.errors])
        if not len(base):
            continue
        lines.append(f"{cfg:<10} {base.mean():>11.3f} " +
                     " ".join(f"{_ms(ratios(results, v, cfg, b)):>26}" for _, v, b in cols))
    classes = sorted({c for r in results for c in r.per_class.get("mono-1", {})})
    for cfg in ("mono-1", "tri-I"):
        for c in classes:
            lines.append(f"{cfg + ' ' + c:<22} " + " ".join(
                f"{_ms(class_ratios(results, v, cfg, c, b)):>26}" for _, v, b in cols))
    for v in variants:
        t = [r.train_s[v] for r in results if v in r.train_s]
        if t:
            lines.append(f"training {VARIANT_TITLES[v]}: {np.mean(t) / 60:.1f} min per seed "
                         f"(all classes and cameras)")
    return "\n".join(lines)
