"""The tables of docs/RESULTS.md "Multi-camera association" from benches/assoc_figures.py's
rows files (a later file's rows replace an earlier one's for the same input, seed, stage and
configuration).

    PYTHONPATH=. .venv/bin/python benches/assoc_table.py DIR/rows-bgsub-103-default.json ...

Two comparisons with the configuration's cameras alone, side by side:

* as measured (each run on the truth *its* cameras see): recall against the best camera's,
  precision and mean error against their mean;
* on the same truth (``same_truth`` of the rows, from assoc_figures.py): recall against the best
  camera alone scored on the configuration's truth, and the mean error on the common matched set
  (truth rows the configuration's run and every one of its cameras alone matched) against the
  cameras' mean there. Rows without ``same_truth`` (older rows files) show "-".
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np

MULTI = {"stereo-10": ["c1", "c3"], "tri-I": ["c0", "c1", "c2"], "tri-T": ["c0", "c2", "c4"],
         "all": ["c0", "c1", "c2", "c3", "c4"]}


def ok(v: float, ref: float, hi: bool = True) -> str:
    """v, bold when it meets the goal (>= ref, or <= ref with hi False)."""
    return f"**{v:.3f}**" if (v >= ref if hi else v <= ref) else f"{v:.3f}"


def same_truth_cells(a: dict) -> tuple[str, str, float, float]:
    """(recall against the best camera alone on the same truth, common-set error cell,
    recall difference, error difference); '-' and NaN without ``same_truth``."""
    st = a.get("same_truth")
    if not st:
        return "-", "-", float("nan"), float("nan")
    best = max(x["recall"] for x in st["alone"].values())
    c = st["common"]
    return (f"{ok(a['recall'], best)} ({best:.3f})",
            f"{ok(c['error_m'], c['alone_mean_error_m'], False)} m ({c['alone_mean_error_m']:.3f}; n {c['n']})",
            a["recall"] - best, c["error_m"] - c["alone_mean_error_m"])


def main() -> None:
    rows = [r for p in sys.argv[1:] for r in json.loads(open(p).read())]
    by = defaultdict(dict)
    for r in rows:
        by[(r["input"], r["seed"])][(r["stage"], r["config"])] = r
    print("| input | seed | configuration | recall (best of its cameras alone) | recall, same truth (best alone) "
          "| precision (their mean) | mean error (their mean) | error, common matched set (their mean; n) "
          "| id consistency | before association: recall / precision / id consistency |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    summary = defaultdict(list)
    for (inp, seed), d in sorted(by.items()):
        for name, cams in MULTI.items():
            a = d.get(("associated", name))
            if a is None:
                continue
            alone = [d[("alone", c)] for c in cams if ("alone", c) in d]
            best = max(x["recall"] for x in alone)
            prec = float(np.mean([x["precision"] for x in alone]))
            err = float(np.mean([x["error_m"] for x in alone]))
            b = d.get(("unassociated", name))
            before = (f"{b['recall']:.3f} / {b['precision']:.3f} / {b['id_consistency']:.3f}"
                      if b else "-")
            rec_same, err_common, d_rec, d_err = same_truth_cells(a)
            print(f"| {inp} | {seed} | {name} | {ok(a['recall'], best)} ({best:.3f}) | {rec_same} | "
                  f"{ok(a['precision'], 0.9)} ({prec:.3f}) | {ok(a['error_m'], err, False)} m ({err:.3f}) | "
                  f"{err_common} | {ok(a['id_consistency'], 0.95)} | {before} |")
            summary[(inp, name)].append((a["recall"] - best, d_rec, a["precision"], a["precision"] - prec,
                                         a["error_m"] - err, d_err, a["id_consistency"]))
    print()
    print("| input | configuration | recall - best alone | same truth: recall - best alone | precision "
          "| precision - mean alone | error - mean alone | common set: error - mean alone | id consistency |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (inp, name), vals in sorted(summary.items()):
        v = np.array(vals)

        def cell(k: int, f: str = "+.3f") -> str:
            x = v[:, k][np.isfinite(v[:, k])]
            return f"{x.mean():{f}} ({x.min():{f}} to {x.max():{f}})" if len(x) else "-"
        print(f"| {inp} | {name} | {cell(0)} | {cell(1)} | {cell(2, '.3f')} | {cell(3)} | {cell(4)} m "
              f"| {cell(5)} m | {cell(6, '.3f')} |")


if __name__ == "__main__":
    main()
