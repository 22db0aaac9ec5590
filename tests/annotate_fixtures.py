"""Helpers for the annotation engine tests: random edit sequences and state digests."""

from __future__ import annotations

import hashlib
import json


def state(p) -> dict:
    """The tracks of a project as plain dicts."""
    return {t: tr.to_dict() for t, tr in p.tracks.items()}


def digest(p) -> str:
    """A hash of the tracks and the undo history."""
    blob = json.dumps([sorted(state(p).items()), p.history()], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def random_edit(p, rng, n_frames: int = 30, allow_undo: bool = True):
    """One random edit of any kind (explicit headings, so no interpolation is needed)."""
    ids = sorted(p.tracks)
    r = rng.random()
    if not ids or r < 0.1:
        return p.create_track(rng.choice(["car", "pedestrian", "bicyclist"]))
    t = rng.choice(ids)
    f = rng.randrange(n_frames)
    if r < 0.5:
        if p.track(t).span_at(f) == "outside":
            return p.mark(t, f, f, "visible")
        return p.set_keyframe(t, f, rng.uniform(-10, 10), rng.uniform(-8, 8),
                              heading=rng.uniform(-3, 3))
    kfs = p.track(t).frames
    if r < 0.6 and kfs:
        return p.nudge(t, rng.choice(kfs), 0.1, -0.02)
    if r < 0.65 and kfs:
        return p.rotate(t, rng.choice(kfs), 5)
    if r < 0.7 and kfs:
        return p.delete_keyframe(t, rng.choice(kfs))
    if r < 0.75:
        return p.mark(t, f, min(f + 5, n_frames - 1), rng.choice(["occluded", "outside", "visible"]))
    if r < 0.8:
        return p.set_class(t, rng.choice(["car", "pedestrian"]), resize=True)
    if r < 0.85 and len(kfs) >= 2:
        return p.split_track(t, kfs[-1])
    if r < 0.9 and len(ids) >= 2:
        a, b = rng.sample(ids, 2)
        if not set(p.track(a).keyframes) & set(p.track(b).keyframes):
            return p.merge_tracks(a, b)
    if r < 0.93 and p.can_undo and allow_undo:
        return p.undo()
    if r < 0.95:
        return p.delete_track(t)
    return p.set_size(t, (rng.uniform(1, 5), 1.5, 1.5))
