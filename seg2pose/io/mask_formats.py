"""Instance-mask files in any supported format: MOTS txt, COCO RLE JSON, or a folder of
instance-id PNGs, read into / written from a MaskTable."""

from __future__ import annotations

from pathlib import Path

from seg2pose.core.errors import InputError
from seg2pose.io.atomic import replacing
from seg2pose.io.coco import read_coco, write_coco
from seg2pose.io.mots import read_mots, write_mots

MASK_FORMATS = ("mots", "coco", "png")


def detect_mask_format(path: Path) -> str:
    """'png' for a folder, 'coco' for .json, 'mots' otherwise."""
    if path.is_dir():
        return "png"
    return "coco" if path.suffix.lower() == ".json" else "mots"


def read_masks(path: str | Path, fmt: str | None = None, known_classes=None):
    """A masks file/folder in any supported format -> MaskTable."""
    from seg2pose.io.png import read_png_folder  # lazy: loads OpenCV

    path = Path(path)
    if not path.exists():
        raise InputError("masks not found", file=path)
    fmt = fmt or detect_mask_format(path)
    if fmt == "mots":
        return read_mots(path, known_classes)
    if fmt == "coco":
        return read_coco(path, known_classes)
    if fmt == "png":
        return read_png_folder(path, known_classes)
    raise InputError(f"unknown mask format {fmt!r}; use one of {', '.join(MASK_FORMATS)}",
                     field="format")


def write_masks(path: str | Path, table, fmt: str) -> None:
    from seg2pose.io.png import write_png_folder  # lazy: loads OpenCV

    if fmt == "mots":
        write_mots(path, table)
    elif fmt == "coco":
        write_coco(path, table)
    elif fmt == "png":
        write_png_folder(path, table)
    else:
        raise InputError(f"unknown mask format {fmt!r}; use one of {', '.join(MASK_FORMATS)}",
                         field="format")


def save_masks(path: str | Path, table, fmt: str, force: bool = False) -> None:
    """Write ``table`` to ``path`` as one unit: built beside it and swapped in, so an
    existing output is replaced entirely (``force``; a PNG folder keeps none of its old
    frames) and an interrupted write leaves it as it was."""
    if fmt not in MASK_FORMATS:
        raise InputError(f"unknown mask format {fmt!r}; use one of {', '.join(MASK_FORMATS)}",
                         field="format")
    with replacing(path, force, folder=fmt == "png") as tmp:
        write_masks(tmp, table, fmt)
