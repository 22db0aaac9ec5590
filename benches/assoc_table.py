"""The tables of docs/RESULTS.md "Multi-camera association" from benches/assoc_figures.py's
rows files.

    PYTHONPATH=. .venv/bin/python benches/assoc_table.py DIR/rows-bgsub-103-default.json ...
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np

MULTI = {"stereo-10": ["c1", "c3"], "tri-I": ["c0", "c1", "c2"], "tri-T": ["c0", "c2", "c4"],
         "all": ["c0", "c1", "c2", "c3", "c4"]}


def main() -> None:
    rows = [r for p in sys.argv[1:] for r in json.loads(open(p).read())]
    by = defaultdict(dict)
    for r in rows:
        by[(r["input"], r["seed"])][(r["stage"], r["config"])] = r
    print("| input | seed | configuration | recall (best of its cameras alone) | precision (their mean) "
          "| mean error (their mean) | id consistency | before association: recall / precision / id consistency |")
    print("|---|---|---|---|---|---|---|---|")
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
            ok = lambda v, ref, hi=True: f"**{v:.3f}**" if (v >= ref if hi else v <= ref) else f"{v:.3f}"
            print(f"| {inp} | {seed} | {name} | {ok(a['recall'], best)} ({best:.3f}) | "
                  f"{ok(a['precision'], 0.9)} ({prec:.3f}) | {ok(a['error_m'], err, False)} m ({err:.3f}) | "
                  f"{ok(a['id_consistency'], 0.95)} | {before} |")
            summary[(inp, name)].append((a["recall"] - best, a["precision"], a["precision"] - prec,
                                         a["error_m"] - err, a["id_consistency"]))
    print()
    print("| input | configuration | recall - best alone | precision | precision - mean alone | error - mean alone | id consistency |")
    print("|---|---|---|---|---|---|---|")
    for (inp, name), vals in sorted(summary.items()):
        v = np.array(vals)
        cell = lambda k, f="+.3f": f"{v[:, k].mean():{f}} ({v[:, k].min():{f}} to {v[:, k].max():{f}})"
        print(f"| {inp} | {name} | {cell(0)} | {cell(1, '.3f')} | {cell(2)} | {cell(3)} m | {cell(4, '.3f')} |")


if __name__ == "__main__":
    main()
