"""A rig of two poles 36 m apart for ``s2p synth --rig``: the device's lens c1 (10 m pole at
(-12, -12), as in every preset) and a second camera e1 on a 10 m pole at (24, -12) looking at
the junction (92 % of what c1 sees is in e1's image too). The scene where cameras disagree on a
wrong height (docs/RESULTS.md, "Track consistency").

    .venv/bin/python benches/two_pole_rig.py OUT.json
    s2p synth --preset bench --seed N --rig OUT.json -o SCENE

Configurations: mono-1 (c1), mono-e (e1), two-pole (c1 + e1).
"""

from __future__ import annotations

import json
import sys

from seg2pose.geometry.camera import Camera
from seg2pose.synth.rig import FOCAL, HEIGHT, WIDTH, make_device


def two_pole_rig() -> dict:
    c1 = make_device("device").cameras["c1"]
    e1 = Camera.look_at("e1", [24.0, -12.0, 10.0], [12.5, -1.7, 0.0], FOCAL, WIDTH, HEIGHT)
    return {"rig": "two-pole", "cameras": [c1.to_dict(), e1.to_dict()],
            "configs": {"mono-1": ["c1"], "mono-e": ["e1"], "two-pole": ["c1", "e1"]}}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    with open(sys.argv[1], "w", encoding="utf-8") as f:
        json.dump(two_pole_rig(), f, indent=1)
