"""What the command families share: the help panels of ``s2p --help`` and option parsers."""

from __future__ import annotations

from seg2pose.errors import InputError

# the groups of ``s2p --help`` (typer's rich_help_panel)
SCENE = "Scene"
METHOD = "Method"
REVIEW = "Review"
ANNOTATION = "Annotation"
BATCH = "Batch"


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """``A:B`` (inclusive) -> (A, B); None stays None."""
    if text is None:
        return None
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a, b = int(parts[0]), int(parts[1])
    except ValueError:
        raise InputError(f"expected A:B with integer frames, got {text!r}", field="--frames") from None
    if a < 0 or b < a:
        raise InputError(f"expected 0 <= A <= B, got {text!r}", field="--frames")
    return a, b
