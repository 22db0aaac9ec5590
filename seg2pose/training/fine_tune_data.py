"""What ``s2p train SCENE --from MODELS`` fine-tunes and on what: the start models of a folder
checked against the scene (one line naming what does not fit), and the scene's annotated masks
as weighted examples, split by road user into training and held-out validation.

Annotated truth (``gt/poses.csv``) says per row where it came from (``source``). Rows the
annotator placed or checked count more than rows filled in between them (``SOURCE_WEIGHTS``:
the chance of an example being drawn into a batch is proportional to it); estimates nobody
checked and occluded rows are not used. A file without the column (full truth) weighs every
row the same. The test split's frames are never used (held out for evaluation).

Validation holds out whole road users (``VAL_SHARE`` of a class's annotated road users, at
least one when it has two or more): early stopping on frames of a road user the network also
trains on would measure how well it remembers that road user, not how well it generalises.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seg2pose.core.errors import S2PError
from seg2pose.core.say import say
from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD
from seg2pose.io.poses import PoseTable
from seg2pose.io.scene import Scene
from seg2pose.method.checkpoint import Checkpoint, baseline_marker_name, model_filename, radial_correction
from seg2pose.structures.masks import rle_stats
from seg2pose.training.examples import ExampleSet, labelled_examples, masks_matched_to_truth

# a row a person placed or accepted one by one (CHECKED_KEYFRAME_SOURCES) counts four times a
# row interpolated between them, an interpolated row the annotator played back and passed twice
SOURCE_WEIGHTS = {"keyframe": 4.0, "estimate-accepted": 4.0, "reviewed": 2.0,
                  "interpolated": 1.0, "": 1.0}  # "": truth without a source column
SKIPPED_SOURCES = ("estimate-unchecked", "occluded")
VAL_SHARE = 0.2


@dataclass
class StartModel:
    """One start checkpoint and the models it becomes: key (class name or '*'), camera key
    (camera name or '*'), the scene cameras it serves, its file."""

    key: str
    camera: str
    cameras: list[str]
    path: Path
    ck: Checkpoint

    @property
    def classes(self) -> list[str]:
        return self.ck.classes if self.key == "*" else [self.key]


def start_models(scene: Scene, folder: Path, cams: list[str], classes: list[str]) -> list[StartModel]:
    """The start models in ``folder`` for ``cams`` x ``classes`` (looked up as ``s2p run``
    does: camera__class, camera__all, all__class, all__all); an S2PError of one line naming
    what does not fit: a camera or class without a model, a model for another image size or
    another class list."""
    folder = Path(folder)
    files = sorted(folder.glob("*__*.safetensors"))
    members = sorted(p.parent for p in folder.glob("*/*__*.safetensors"))
    if not files and (folder / "demo_models.json").exists() and members:
        # the shipped demo models' folder: its first member (one training scene's models)
        say(f"{folder}: starting from its first member, {members[0].name}", "note")
        return start_models(scene, members[0], cams, classes)
    if not files:
        raise S2PError(f"{folder}: no Seg2PoseNet models (*__*.safetensors) to start from")
    have = {p.name: p for p in files}
    found: dict[Path, StartModel] = {}
    chosen = baseline_markers(folder, cams, classes)
    for cam in cams:
        for cls in classes:
            if (cam, cls) in chosen:
                continue  # the start runs the baseline there (fine_tune_scene keeps its marker)
            names = [model_filename(cam, cls), model_filename(cam, "*"), model_filename("*", cls),
                     model_filename("*", "*")]
            path = next((have[n] for n in names if n in have), None)
            if path is None:
                raise S2PError(_missing(folder, files, cam, cls, scene))
            if path not in found:
                ck = Checkpoint.load(path)
                key = "*" if path.name.endswith("__all.safetensors") else cls
                camkey = "*" if path.name.startswith("all__") else cam
                found[path] = StartModel(key, camkey, [], path, ck)
            sm = found[path]
            if cam not in sm.cameras:
                sm.cameras.append(cam)
    for sm in found.values():
        c = scene.cameras[sm.cameras[0]]
        if (sm.ck.norm.width, sm.ck.norm.height) != (c.width, c.height):
            raise S2PError(f"{sm.path} was made for {sm.ck.norm.width}x{sm.ck.norm.height} images; "
                           f"camera {c.name} of {scene.root} has {c.width}x{c.height}")
        if sm.key == "*" and list(sm.ck.classes) != list(scene.class_names):
            raise S2PError(f"{sm.path} is for classes {', '.join(sm.ck.classes)}; {scene.root} has "
                           f"{', '.join(scene.class_names)}")
    return list(found.values())


def baseline_markers(folder: Path, cams: list[str], classes: list[str]) -> dict[tuple[str, str], Path]:
    """(camera, class) -> the marker of a folder that runs the baseline there (an earlier
    fine-tuning's choice, ``fine_tune_choice``), met before a model in ``s2p run``'s lookup."""
    out = {}
    for cam in cams:
        for cls in classes:
            for c, k in ((cam, cls), (cam, "*"), ("*", cls), ("*", "*")):
                if (Path(folder) / model_filename(c, k)).exists():
                    break
                marker = Path(folder) / baseline_marker_name(c, k)
                if marker.exists():
                    out[(cam, cls)] = marker
                    break
    return out


def _missing(folder: Path, files: list[Path], cam: str, cls: str, scene: Scene) -> str:
    """The one line saying why ``folder`` has no model for camera ``cam`` and class ``cls``."""
    cams = sorted({p.name.split("__")[0] for p in files})
    kinds = sorted({p.name.split("__")[1].removesuffix(".safetensors") for p in files})
    if "all" not in cams and cam not in cams:
        return (f"{folder} holds models for cameras {', '.join(cams)}; {scene.root} has "
                f"{', '.join(scene.cameras)} (models of other cameras cannot start this scene)")
    return (f"{folder} has no model for class {cls} (its models are for {', '.join(kinds)}; "
            f"{scene.root} has classes {', '.join(scene.class_names)})")


@dataclass
class Annotated:
    """Annotated masks of one camera: rles (N,), class names, true x, y (N, 2) metres, source
    (N,) str, road user (truth track id) (N,), box IoU (N,) of each mask with its annotated road
    user's projected 3D box (``truth_box_iou``; low: a merged or cut mask)."""

    camera: str
    rles: list[bytes]
    cls: np.ndarray
    xy: np.ndarray
    source: np.ndarray
    road_user: np.ndarray
    iou: np.ndarray

    def take(self, idx: np.ndarray) -> Annotated:
        return Annotated(self.camera, [self.rles[i] for i in idx], self.cls[idx], self.xy[idx],
                         self.source[idx], self.road_user[idx], self.iou[idx])


def usable_rows(gt: PoseTable, scene: Scene) -> PoseTable:
    """The annotated rows fine-tuning may use: sources with a weight, frames outside the test
    split (says how many of each source were skipped)."""
    src = gt.source if gt.source is not None else np.full(len(gt), "", object)
    keep = np.isin(src, list(SOURCE_WEIGHTS))
    for s in sorted(set(src[~keep].tolist())):
        why = "not used" if s in SKIPPED_SOURCES else "an unknown source; not used"
        say(f"{int((src == s).sum())} annotated rows of source {s!r}: {why}", "note")
    if "test" in scene.splits:
        a, b = scene.splits["test"]
        keep &= (gt.frame < a) | (gt.frame > b)
    out = gt.take(np.flatnonzero(keep))
    if out.source is None:
        out.source = np.full(len(out), "", object)
    return out


def annotated_masks(scene: Scene, camera: str, gt: PoseTable) -> Annotated:
    """``camera``'s masks matched to the annotated rows ``gt`` (sorted by frame; paper 4.1's
    matching, ``match_masks_to_truth``), streamed a few hundred frames at a time."""
    by_id, sizes, cam = scene.class_by_id(), scene.class_sizes(), scene.cameras[camera]
    rles, cls, xy, src, ru, iou = [], [], [], [], [], []
    frames = np.unique(gt.frame)
    span = (int(frames[0]), int(frames[-1])) if len(frames) else None
    for t, g, match in (masks_matched_to_truth(scene, camera, gt, span) if span else ()):
        assert g.source is not None  # rows from usable_rows always carry their source
        hit = np.flatnonzero(match >= 0)
        if len(hit):
            rows = match[hit]
            size = (g.size[rows] if g.size is not None else
                    np.array([sizes.get(str(c), (1.0, 1.0, 1.6)) for c in g.cls[rows]], float))
            iou.append(truth_box_iou(cam, g.xyz[rows], g.heading[rows], size,
                                     rle_stats([t.rles[i] for i in hit], t.height, t.width)[2]))
        for i in hit:
            rles.append(t.rles[i])
            cls.append(by_id[int(t.class_id[i])].name)
            xy.append(g.xyz[match[i], :2])
            src.append(str(g.source[match[i]]))
            ru.append(int(g.track_id[match[i]]))
    return Annotated(camera, rles, np.array(cls, object), np.array(xy, float).reshape(-1, 2),
                     np.array(src, object), np.array(ru, np.int64),
                     np.concatenate(iou) if iou else np.zeros(0))


def truth_box_iou(cam, xyz: np.ndarray, heading: np.ndarray, size: np.ndarray,
                  boxes: np.ndarray) -> np.ndarray:
    """IoU (N,) of mask bounding boxes (N, 4) x0, y0, x1, y1 pixels with the bounding boxes of
    the projected 3D boxes of road users at ``xyz`` (N, 3) metres (bottom centre), ``heading``
    (N,) radians (NaN: the footprint as a square of the larger side), ``size`` (N, 3) l, w, h
    metres. 0 where a corner is behind the camera or a box is empty."""
    h = np.nan_to_num(np.asarray(heading, float))
    sq = ~np.isfinite(np.asarray(heading, float))
    ln = np.where(sq, np.maximum(size[:, 0], size[:, 1]), size[:, 0]) / 2
    wd = np.where(sq, np.maximum(size[:, 0], size[:, 1]), size[:, 1]) / 2
    sx = np.array([1, 1, -1, -1] * 2, float)
    sy = np.array([1, -1, -1, 1] * 2, float)
    sz = np.array([0] * 4 + [1] * 4, float)
    c, s_ = np.cos(h)[:, None], np.sin(h)[:, None]
    dx, dy = ln[:, None] * sx, wd[:, None] * sy
    pts = np.stack([xyz[:, None, 0] + c * dx - s_ * dy, xyz[:, None, 1] + s_ * dx + c * dy,
                    xyz[:, None, 2] + size[:, None, 2] * sz], axis=2)  # (N, 8, 3)
    uv, _, front = cam.project_points(pts.reshape(-1, 3))
    uv, front = uv.reshape(-1, 8, 2), front.reshape(-1, 8).all(axis=1)
    tb = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)
    ix = np.clip(np.minimum(tb[:, 2], boxes[:, 2]) - np.maximum(tb[:, 0], boxes[:, 0]), 0, None)
    iy = np.clip(np.minimum(tb[:, 3], boxes[:, 3]) - np.maximum(tb[:, 1], boxes[:, 1]), 0, None)
    inter = ix * iy
    union = ((tb[:, 2] - tb[:, 0]) * (tb[:, 3] - tb[:, 1])
             + (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]) - inter)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(union > 0, inter / union, 0.0)
    return np.where(front & np.isfinite(out), out, 0.0)


def held_out_road_users(road_user: np.ndarray, cls: np.ndarray, seed: int,
                        min_users: int = 2) -> np.ndarray:
    """The road users (truth track ids) held out for validation: per class, ``VAL_SHARE`` of
    its annotated road users (rounded, at least one when it has ``min_users`` or more, none
    with fewer)."""
    rng = np.random.default_rng(seed)
    out = []
    for c in sorted(set(cls.tolist())):
        users = np.unique(road_user[cls == c])
        k = 0 if len(users) < max(2, min_users) else max(1, int(round(VAL_SHARE * len(users))))
        out.append(rng.choice(users, k, replace=False) if k else np.zeros(0, np.int64))
    return np.concatenate(out) if out else np.zeros(0, np.int64)


@dataclass
class WeightedExamples:
    """Examples with a sampling weight each (N,), the road users they show (N,) and the
    baseline's error on each (N,) metres: the distance from the normal position to the truth."""

    ex: ExampleSet
    weight: np.ndarray
    road_user: np.ndarray
    baseline_error: np.ndarray

    @classmethod
    def empty(cls, crop: int, factor: int) -> WeightedExamples:
        return cls(ExampleSet.empty(crop // factor, factor), np.zeros(0), np.zeros(0, np.int64),
                   np.zeros(0))

    def take(self, idx: np.ndarray) -> WeightedExamples:
        return WeightedExamples(self.ex.take(idx), self.weight[idx], self.road_user[idx],
                                self.baseline_error[idx])

    @classmethod
    def concat(cls, parts: list[WeightedExamples], crop: int, factor: int) -> WeightedExamples:
        parts = [p for p in parts if len(p.ex)]
        if not parts:
            return cls.empty(crop, factor)
        return cls(ExampleSet.concat([p.ex for p in parts]), np.concatenate([p.weight for p in parts]),
                   np.concatenate([p.road_user for p in parts]),
                   np.concatenate([p.baseline_error for p in parts]))


def weighted_examples(scene: Scene, ann: Annotated, crop: int, factor: int,
                      center_method: str = DEFAULT_CENTER_METHOD,
                      radial_offset: dict[str, float] | None = None,
                      min_iou: float = 0.0) -> WeightedExamples:
    """Examples of ``ann``'s masks (``labelled_examples``: normal positions at the class
    heights, targets = truth - normal), one call per (source, road user, whole mask or not) so
    every example keeps its weight and road user. ``radial_offset``: the start model's
    (subtracted at prediction); it is added to the targets so that the fine-tuned model, which
    keeps it, predicts the truth. ``min_iou``: masks whose box IoU with their road user's
    projected 3D box is below it (merged, cut) get weight 0: never drawn for training, still
    scored when the candidates are compared (``fine_tune_choice``)."""
    parts: list[WeightedExamples] = []
    cam = scene.cameras[ann.camera]
    whole = ann.iou >= min_iou
    groups = sorted({(str(a), int(b), bool(c)) for a, b, c in zip(ann.source, ann.road_user, whole)})
    for s, u, ok in groups:
        idx = np.flatnonzero((ann.source == s) & (ann.road_user == u) & (whole == ok))
        sub = ann.take(idx)
        ex = labelled_examples(scene, ann.camera, sub.rles, cam.height, cam.width, sub.cls,
                               sub.xy, False, crop, factor, center_method)
        if not len(ex):
            continue
        base = np.linalg.norm(ex.target, axis=1)  # before the start's offset: the baseline's
        if radial_offset:
            ex.target = ex.target + radial_correction(radial_offset, ex.cls, ex.normal,
                                                      cam.center[:2])
        parts.append(WeightedExamples(ex, np.full(len(ex), SOURCE_WEIGHTS[s] if ok else 0.0),
                                      np.full(len(ex), u, np.int64), base))
    return WeightedExamples.concat(parts, crop, factor)


def split_by_road_user(w: WeightedExamples, val_users: np.ndarray
                       ) -> tuple[WeightedExamples, WeightedExamples]:
    """(training, validation): the examples of the road users ``val_users`` validate."""
    is_val = np.isin(w.road_user, val_users)
    return w.take(np.flatnonzero(~is_val)), w.take(np.flatnonzero(is_val))


def scratch_start(scene: Scene, folder: Path, arch: str = "lite-hr", geometry: bool = True,
                  seed: int = 0) -> list[Path]:
    """Freshly initialised models (one per class for all cameras, ``all__<class>``: the quick
    protocol's layout) in ``folder``: a start "from scratch" for ``fine_tune_scene``, to
    measure what a start model is worth. Returns the files written."""
    import torch

    from seg2pose.method.features import GEO_VERSION, N_GEO
    from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet

    cam = next(iter(scene.cameras.values()))
    norm = Normalisation.for_scene(scene.ground_points, cam.width, cam.height)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for cls in scene.class_names:
        torch.manual_seed(seed)
        ck = Checkpoint(net=Seg2PoseNet(NetConfig.named(arch, 0, N_GEO if geometry else 0)),
                        norm=norm, camera="*", cls=cls, scene_fingerprint=scene.fingerprint(),
                        info={"complete": True, "scratch": True, "cameras": list(scene.cameras),
                              "geometry": GEO_VERSION if geometry else None})
        ck.save(folder / model_filename("*", cls))
        out.append(folder / model_filename("*", cls))
    return out
