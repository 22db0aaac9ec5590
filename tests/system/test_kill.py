"""SIGKILL at random moments (issue 10): ``s2p run``, ``synth``, ``convert-masks``,
``import-utocs`` and ``export`` leave their output absent, the complete old one or the complete
new one, never a mix, and beside it only what the next writer cleans up.
20 kills in all (seeded); benches/bench_faults.py does 200 per command."""

from __future__ import annotations

import numpy as np
import pytest

from kill_harness import build_cases

KILLS_PER_COMMAND = 4


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    cs = build_cases(tmp_path_factory.mktemp("kill"), frames=20)
    for c in cs:
        c.run_fully()
    return cs


@pytest.mark.parametrize("name", ["run", "synth", "convert-masks", "import-utocs", "export"])
def test_killed_command_leaves_old_or_new(cases, name):
    case = next(c for c in cases if c.name == name)
    rng = np.random.default_rng(sum(map(ord, name)))
    kinds = [case.kill_once(rng) for _ in range(KILLS_PER_COMMAND)]
    assert case.counts["mixed"] == 0, kinds
    assert case.new is not None and case.new != {}
    # what a killed writer leaves beside the output is only what the next writer removes (its
    # lock and partial build; tests/system/test_atomic_outputs.py checks that removal, and
    # benches/bench_faults.py after every command)
    assert case.live_leftovers() == []
