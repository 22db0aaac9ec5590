"""Ground truth gives every visit its own track id (a road user that leaves and comes back,
or a population slot used again, is a new road user to a tracker), while its shape -- and so
every rendered pixel -- stays the road user's."""

from __future__ import annotations

import numpy as np

from seg2pose.safety.gaps import jumps
from seg2pose.safety.tracks import from_poses
from seg2pose.synth.traffic import Visit
from seg2pose.synth.world import build_world


def visit(member: int, f0: int, n: int, x0: float) -> Visit:
    f = np.arange(f0, f0 + n)
    xy = np.c_[x0 + 0.5 * np.arange(n), np.zeros(n)]
    return Visit("car", f, xy, np.zeros(n), np.zeros(n), f0 * 0.075, member)


def test_a_returning_road_user_gets_a_new_id_and_keeps_its_shape():
    """Member 0 passes twice (frames 0-9 at x = 0, frames 10-19 at x = 100: a 100 m jump
    under one id before); member 1 once. Ids by first appearance: 1, 2 (member 1), 3."""
    visits = [visit(0, 0, 10, 0.0), visit(1, 5, 10, 50.0), visit(0, 10, 10, 100.0)]
    w = build_world(visits, 20, seed=3)
    poses = w.poses()
    ids = {int(t): sorted({int(x) for x in w.track[w.ids == t]}) for t in np.unique(w.ids)}
    assert ids == {1: [1], 2: [2], 3: [1]}  # visit ids -> the road user's shape
    assert sorted(np.unique(poses.track_id)) == [1, 2, 3]
    tracks, _ = from_poses(poses, 13.333)
    assert len(jumps(tracks)) == 0
    one_id = build_world(visits, 20, seed=3)
    one_id.visit = None  # as before: one id per road user
    tracks1, _ = from_poses(one_id.poses(), 13.333)
    assert len(jumps(tracks1)) == 1
