"""The edit history of a ``Project``: its in-memory state (tracks, undo and redo stacks) and
how journal records and snapshots change it. Used the same way by edits made now and by the
replay of the journal, so that both give the same state."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from annotate import journal as J
from annotate.model import Track

UNDO_LIMIT = 10_000      # edits kept for undo (the oldest are forgotten beyond this)


@dataclass(slots=True)
class Entry:
    seq: int
    name: str
    ops: list[dict]
    inverse: list[dict]


@dataclass
class State:
    tracks: dict[int, Track] = field(default_factory=dict)
    undo: list[Entry] = field(default_factory=list)
    redo: list[Entry] = field(default_factory=list)
    seq: int = 0


def record_edit(s: State, e: Entry) -> None:
    """A new edit joins the undo history (the oldest forgotten beyond UNDO_LIMIT) and ends the
    redo history: the same for edits made now and edits replayed from the journal."""
    s.undo.append(e)
    if len(s.undo) > UNDO_LIMIT:
        del s.undo[: len(s.undo) - UNDO_LIMIT]
    s.redo.clear()


def swap(s: State, kind: str, of: int) -> Entry:
    """Move edit ``of`` from the top of the undo history to the redo one (``kind`` "undo") or
    back ("redo"); returns it. Raises ValueError when it is not on top (a damaged journal)."""
    src, dst = (s.undo, s.redo) if kind == "undo" else (s.redo, s.undo)
    if not src or src[-1].seq != of:
        raise ValueError(f"{kind} of edit {of}, which is not next to {kind}")
    dst.append(src.pop())
    return dst[-1]


def step_ops(e: Entry, kind: str) -> list[dict]:
    """The ops that undo (its inverse) or redo (its ops) edit ``e``."""
    return e.inverse if kind == "undo" else e.ops


def snapshot_dict(s: State, scene: str, fingerprint: str) -> dict:
    ent = lambda e: [e.seq, e.name, e.ops, e.inverse]  # noqa: E731
    return {"kind": "snapshot", "version": J.VERSION, "scene": scene, "fingerprint": fingerprint,
            "seq": s.seq, "tracks": [t.to_dict() for _, t in sorted(s.tracks.items())],
            "undo": [ent(e) for e in s.undo], "redo": [ent(e) for e in s.redo]}


def state_from_snapshot(d: dict, path: Path, fingerprint: str) -> State:
    J.check_header(d, path, fingerprint)
    try:
        tracks = {int(t["id"]): Track.from_dict(t) for t in d["tracks"]}
        ent = lambda r: Entry(int(r[0]), str(r[1]), r[2], r[3])  # noqa: E731
        return State(tracks, [ent(r) for r in d["undo"]], [ent(r) for r in d["redo"]],
                      int(d["seq"]))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise J.JournalError(f"{path}: not a valid snapshot ({e})") from None

