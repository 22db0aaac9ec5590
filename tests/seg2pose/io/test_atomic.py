"""Atomic writes and the --force rule (seg2pose/io/atomic.py) on one file; the kills, disks
and locks of every command are in tests/system/test_atomic_outputs.py."""

import pytest

from seg2pose.core.errors import S2PError
from seg2pose.io.atomic import atomic_write_text, check_writable


def test_atomic_and_check_writable(tmp_path):
    p = tmp_path / "a.txt"
    atomic_write_text(p, "x")
    with pytest.raises(S2PError, match="--force"):
        check_writable(p, force=False)
    assert check_writable(p, force=True) == p
    assert [q.name for q in tmp_path.iterdir()] == ["a.txt"]  # no temporary left behind
