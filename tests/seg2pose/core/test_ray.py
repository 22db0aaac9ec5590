"""``ray_map`` (``s2p train --parallel/--address``) starts a Ray of its own, never joining a
cluster another user started on this machine; checked on a stand-in for the ``ray`` module,
so Ray need not be installed."""

from __future__ import annotations

import pytest

import seg2pose.core.ray as R
from seg2pose.core.errors import S2PError


class FakeRay:
    """What ``ray_map`` uses of ``ray``: records ``init``'s arguments and runs tasks inline."""

    def __init__(self):
        self.inits: list[dict] = []

    def is_initialized(self) -> bool:
        return bool(self.inits)

    def init(self, **kwargs):
        self.inits.append(kwargs)

    def remote(self, **options):
        assert options == {"max_retries": R.MAX_RETRIES}

        class Task:
            def __init__(self, fn):
                self.fn = fn

            def remote(self, x):
                return self.fn(x)
        return Task

    @staticmethod
    def get(refs):
        return list(refs)


@pytest.mark.parametrize("address,cpus,want", [
    (None, 3, {"address": "local", "num_cpus": 3}),   # --parallel 3: a local Ray of 3 CPUs
    (None, None, {"address": "local", "num_cpus": None}),
    ("auto", 3, {"address": "auto", "num_cpus": None}),  # --address: the named cluster's CPUs
])
def test_ray_map_starts_its_own_ray_unless_given_an_address(monkeypatch, address, cpus, want):
    fake = FakeRay()
    monkeypatch.setattr(R, "import_ray", lambda: fake)
    mapper = R.ray_map(address, cpus)
    assert fake.inits == []  # nothing started before the first map
    assert mapper(lambda x: x * x, [1, 2, 3]) == [1, 4, 9]
    assert mapper(lambda x: -x, [4]) == [-4]
    assert fake.inits == [dict(want, log_to_driver=True)]  # started once, then reused


def test_ray_map_without_ray_says_how_to_install_it(monkeypatch):
    monkeypatch.setattr(R, "import_ray", lambda: None)
    with pytest.raises(S2PError, match="seg2pose\\[scale\\]"):
        R.ray_map(None, 2)
