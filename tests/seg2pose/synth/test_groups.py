"""Pedestrians walking in groups (``TrafficConfig.group_share``, ``s2p synth --groups``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seg2pose.core.errors import InputError
from seg2pose.synth.generate import PRESETS, SynthOptions, generate_scene
from seg2pose.synth.traffic import GROUP_LAG, GROUP_SPACING, TrafficConfig, pedestrian_groups, simulate

WIDE = PRESETS["wide"]
N_FRAMES = 900


def traffic(share: float, seed: int = 5):
    cfg = TrafficConfig(population=dict(WIDE["population"]), mean_pause_s=dict(WIDE["mean_pause_s"]),
                        group_share=share)
    stats: dict = {}
    return simulate(cfg, N_FRAMES, 0.075, seed, stats), stats, cfg


def by_member(visits) -> dict[int, list]:
    out: dict[int, list] = {}
    for v in visits:
        out.setdefault(v.member, []).append(v)
    return out


def test_no_groups_is_the_traffic_as_before():
    """share 0 takes nothing from the random streams: the same visits as a config without
    the field, and scene.json's traffic record without a group key."""
    a, sa, cfg = traffic(0.0)
    b, sb, _ = traffic(0.0)
    plain = simulate(TrafficConfig(population=dict(WIDE["population"]),
                                   mean_pause_s=dict(WIDE["mean_pause_s"])), N_FRAMES, 0.075, 5)
    assert len(a) == len(plain) and sa == sb and "groups" not in sa
    for v, w in zip(a, plain):
        assert v.member == w.member and np.array_equal(v.frames, w.frames)
        assert np.array_equal(v.xy, w.xy, equal_nan=True)
    assert "group_share" not in cfg.to_dict()


@pytest.mark.parametrize("share", [0.3, 0.6, 1.0])
def test_groups_partition_the_pedestrians(share):
    slots = list(range(24, 52))
    groups = pedestrian_groups(share, slots, 9)
    members = [m for g in groups.values() for m in g]
    assert len(members) == len(set(members)) and set(members) <= set(slots)
    assert all(2 <= len(g) <= 3 and g[0] == lead and list(g) == sorted(g) for lead, g in groups.items())
    # about the share: every grouped member but at most one left over
    assert round(share * len(slots)) - 1 <= len(members) <= round(share * len(slots))
    assert pedestrian_groups(share, slots, 9) == groups  # its own stream: deterministic
    assert pedestrian_groups(0.0, slots, 9) == {}


def test_a_group_walks_together_on_every_visit():
    visits, stats, _ = traffic(0.5)
    groups = pedestrian_groups(0.5, list(range(24, 52)), 5)
    assert stats["groups"] == len(groups) > 0
    vm = by_member(visits)
    walked = 0
    for g in groups.values():
        lead = vm.get(g[0], [])
        for m in g[1:]:  # the same visits, frame for frame, beside the leader
            assert len(vm.get(m, [])) == len(lead)
        for i, v in enumerate(lead):
            pos = [vm[m][i].xy for m in g]
            assert all(np.array_equal(vm[m][i].frames, v.frames) for m in g)
            # a rigid formation: each member's nearest other member is a neighbour at the
            # side-by-side spacing, stretched at most by two lags along the heading, always
            near = np.min([[np.linalg.norm(pos[a] - pos[b], axis=1) for b in range(len(g)) if b != a]
                           for a in range(len(g))], axis=1)
            assert np.nanmin(near) >= GROUP_SPACING - 1e-9
            assert np.allclose(near, near[:, :1])
            assert np.nanmax(near) < np.hypot(GROUP_SPACING, 2 * GROUP_LAG) + 1e-9
            walked += len(v.frames)
    assert walked > 500


def test_vehicles_yield_to_groups():
    """No vehicle's centre comes within a car's half width of a group member (the group
    counts as one wide walker in the conflict checks)."""
    visits, _, _ = traffic(0.6, seed=3)
    groups = pedestrian_groups(0.6, list(range(24, 52)), 3)
    grouped = {m for g in groups.values() for m in g}
    at = {}
    for v in visits:
        for f, p in zip(v.frames, v.xy):
            at.setdefault(int(f), []).append((v.cls, v.member, p))
    closest = np.inf
    for rows in at.values():
        peds = [p for c, m, p in rows if c == "pedestrian" and m in grouped]
        cars = [p for c, m, p in rows if c == "car"]
        if peds and cars:
            closest = min(closest, float(np.min(np.linalg.norm(
                np.array(peds)[:, None] - np.array(cars)[None], axis=2))))
    assert closest > 0.95


def test_synth_groups_recorded_and_validated(tmp_path):
    out = generate_scene(tmp_path / "g", SynthOptions(preset="small", frames=30, seed=2, progress=False,
                                                      workers=1, groups=0.5))
    gen = json.loads((out / "scene.json").read_text())["extra"]["generator"]
    assert gen["traffic"]["group_share"] == 0.5 and gen["traffic_stats"]["groups"] >= 1
    with pytest.raises(InputError, match="groups"):
        generate_scene(tmp_path / "bad", SynthOptions(preset="small", frames=30, groups=1.5))
    assert not (tmp_path / "bad").exists()
