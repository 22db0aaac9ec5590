"""Seg2PoseNet (paper 3.3, Figure 3): a CNN that refines a normal position from a mask crop.

Reading of Figure 3 (the ``paper`` architecture)
-------------------------------------------------
Input: a 420x420 crop of one instance mask (1 channel, 0/1, zero-padded beyond the image
border) and a 4-vector (x_p, y_p, x_n, y_n): the crop centre in pixels and the normal position.
A "conv block" AxB is two AxB convolutions, each followed by ReLU ("same" padding, so the
spatial size is kept). Feature maps (channels x height x width)::

    1x420x420  --5x5 conv block-->  11x420x420
               --5x5 conv block-->  21x420x420
               --2x2 max-pool--->   21x210x210
               --3x3 conv block-->  31x210x210
               --(3x3 conv block, 2x2 max-pool) x 5-->  39x105², 47x52², 55x26², 63x13², 71x6x6
               --6x6 conv (valid)-> 71x1x1 --flatten--> 71
               --concat 4-vector--> 75
               --(dense 148, ReLU) x 3--> 148
               --dense 2, 2.5 tanh(x)--> 2   (the normalised residual)

The figure gives 31 channels before and 71 after the five pooled blocks but not the widths in
between; we grow them linearly, +8 per block (39, 47, 55, 63, 71), as 11 -> 21 -> 31 grows by
+10. Pooling floors odd sizes (105 -> 52, 13 -> 6), which is how 210 reaches 6 after five
poolings. Whether the 6x6 convolution has a ReLU is not shown; we apply one (every other conv in
the figure has one). The output is "the normalised pose": here a residual in units of
``residual_scale`` metres added to the normal position (section 3.3).

The ``lite`` architecture (for CPUs)
------------------------------------
The same crop downsampled by 3 (420 -> 140, each pixel the covered fraction of a 3x3 block),
blocks of one 3x3 convolution + ReLU + 2x2 max-pool, widths 8-16-24-32-48 (140 -> 4x4), a 4x4
convolution to 64, then the same head (concat, three dense layers of 64, 2.5 tanh). About 1/200
of the paper arch's multiply-adds. (A ``lite2``, the same trunk on the crop downsampled by 2,
did not learn in the one CPU run made with it, docs/RESULTS.md, and was removed.) ``lite-hr`` is the lite trunk on a
full-resolution 140x140 crop centred on the mask centre (no downsampling, same cost as
``lite``; larger masks are cut around their centre); ``Checkpoint.predict`` cuts it from the
centre of the pipeline's 420 crops.

Checkpoint files, inference over many masks and model sets live in ``seg2pose.method.checkpoint``;
the training loop in ``seg2pose.training.train``.

Input normalisation (``Normalisation``; recorded in every checkpoint's metadata)
-----------------------------------------------------------------------------------
- mask crop: 0/1 per pixel (lite: fraction of the 3x3 block, in [0, 1]).
- crop centre (u, v) pixels -> (2 u / W - 1, 2 v / H - 1), i.e. [-1, 1] over the image.
- normal position (x_n, y_n) metres -> ((x_n - cx) / s, (y_n - cy) / s) with the scene centre
  (cx, cy) = mean of the ground points and s = half the larger side of their bounding box.
- output residual (dx, dy) metres = residual_scale * 2.5 tanh(z), residual_scale = 1 m, so a
  view can be moved by at most 2.5 m.
- optional class one-hot appended to the vector (``n_classes`` > 0) when one model serves all
  classes of a camera (the CPU option, see train.py); 0 for the paper's per-class models.
- optional mask-geometry features appended after it (``n_geo`` > 0; ``seg2pose.method.features``,
  scaled there): an extension of the paper's 4-vector, 0 in the paper arch by default.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
from torch import nn

from seg2pose.core.errors import InputError, S2PError

ARCHS = ("paper", "lite", "lite-hr")

# --------------------------------------------------------------------------------------------
# configuration


@dataclass(frozen=True)
class NetConfig:
    """Architecture hyper-parameters. ``stages``: (out_channels, kernel, max-pool after) per
    conv block; ``convs_per_block``: 2 in the paper ("AxB conv, ReLU" twice)."""

    arch: str = "paper"
    crop: int = 420              # crop side in image pixels (paper 3.3)
    downsample: int = 1          # the network sees crop // downsample pixels per side
    stages: tuple = ((11, 5, False), (21, 5, True), (31, 3, False), (39, 3, True),
                     (47, 3, True), (55, 3, True), (63, 3, True), (71, 3, True))
    convs_per_block: int = 2
    head_channels: int = 71      # output of the final (valid) convolution
    n_vec: int = 4               # (x_p, y_p, x_n, y_n)
    n_classes: int = 0           # class one-hot appended to the vector (0 = per-class model)
    n_geo: int = 0               # mask-geometry features appended after it (seg2pose.method.features)
    hidden: int = 148
    n_dense: int = 3
    out_scale: float = 2.5       # the "2.5 tanh(x)" of Figure 3

    @property
    def input_size(self) -> int:
        return self.crop // self.downsample

    @property
    def final_size(self) -> int:
        """Spatial size before the head convolution (6 for the paper arch)."""
        s = self.input_size
        for _, _, pool in self.stages:
            s = s // 2 if pool else s
        return s

    @classmethod
    def paper(cls, n_classes: int = 0) -> NetConfig:
        return cls(n_classes=n_classes)

    @classmethod
    def lite(cls, n_classes: int = 0) -> NetConfig:
        return cls(arch="lite", downsample=3,
                   stages=((8, 3, True), (16, 3, True), (24, 3, True), (32, 3, True), (48, 3, True)),
                   convs_per_block=1, head_channels=64, hidden=64, n_classes=n_classes)

    @classmethod
    def lite_hr(cls, n_classes: int = 0) -> NetConfig:
        """The lite trunk on a full-resolution 140x140 crop centred on the mask centre (no
        downsampling): the same cost as ``lite``, 3x the resolution, 1/9 of the field of view.
        Masks larger than 140 px are cut around their centre (as the paper does at 420)."""
        return cls(arch="lite-hr", crop=140, downsample=1,
                   stages=((8, 3, True), (16, 3, True), (24, 3, True), (32, 3, True), (48, 3, True)),
                   convs_per_block=1, head_channels=64, hidden=64, n_classes=n_classes)

    @classmethod
    def named(cls, arch: str, n_classes: int = 0, n_geo: int = 0) -> NetConfig:
        """The named arch; ``n_geo`` > 0 appends that many mask-geometry features to the vector."""
        makers = {"paper": cls.paper, "lite": cls.lite, "lite-hr": cls.lite_hr,
                  "lite_hr": cls.lite_hr}
        if arch not in makers:
            raise InputError(f"unknown arch {arch!r}; use one of {', '.join(ARCHS)}", field="arch")
        return replace(makers[arch](n_classes), n_geo=int(n_geo))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["stages"] = [list(s) for s in self.stages]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> NetConfig:
        d = dict(d)
        d["stages"] = tuple(tuple(s) for s in d["stages"])
        d.setdefault("n_geo", 0)  # checkpoints from before the geometry features
        return cls(**d)


@dataclass(frozen=True)
class Normalisation:
    """Input/output scaling constants of one model (see the module docstring)."""

    width: int                   # image size, pixels
    height: int
    center_xy: tuple = (0.0, 0.0)  # scene centre, metres
    scale: float = 1.0             # metres per normalised unit of the normal position
    residual_scale: float = 1.0    # metres per unit of the network output

    @classmethod
    def for_scene(cls, ground_points: np.ndarray, width: int, height: int,
                  residual_scale: float = 1.0) -> Normalisation:
        xy = np.asarray(ground_points, float)[:, :2]
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        c = xy.mean(axis=0)
        s = max(float(np.max(hi - lo)) / 2, 1.0)
        return cls(int(width), int(height), (float(c[0]), float(c[1])), s, float(residual_scale))

    def vector(self, centers: np.ndarray, normal_xy: np.ndarray) -> np.ndarray:
        """The network's 4-vector (N, 4) float32 from crop centres (N, 2) pixels and normal
        positions (N, 2) metres."""
        c = np.asarray(centers, np.float64).reshape(-1, 2)
        n = np.asarray(normal_xy, np.float64).reshape(-1, 2)
        v = np.empty((len(c), 4), np.float32)
        v[:, 0] = 2 * c[:, 0] / self.width - 1
        v[:, 1] = 2 * c[:, 1] / self.height - 1
        v[:, 2] = (n[:, 0] - self.center_xy[0]) / self.scale
        v[:, 3] = (n[:, 1] - self.center_xy[1]) / self.scale
        return v

    def to_dict(self) -> dict:
        d = asdict(self)
        d["center_xy"] = list(self.center_xy)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Normalisation:
        d = dict(d)
        d["center_xy"] = tuple(d["center_xy"])
        return cls(**d)


def class_onehot(class_names, classes: list[str]) -> np.ndarray:
    """(N, len(classes)) float32 one-hot of class names in the order of ``classes`` (a row of
    zeros for a name not in it)."""
    out = np.zeros((len(class_names), len(classes)), np.float32)
    idx = {c: i for i, c in enumerate(classes)}
    for i, c in enumerate(class_names):
        j = idx.get(str(c))
        if j is not None:
            out[i, j] = 1.0
    return out


def input_vector(cfg: NetConfig, norm: Normalisation, centers: np.ndarray, normal_xy: np.ndarray,
                 class_names=None, classes: list[str] | tuple[str, ...] = (), geo: np.ndarray | None = None
                 ) -> np.ndarray:
    """The network's vector input (N, n_vec + n_classes + n_geo) float32: the normalised crop
    centre and normal position, then (when the net has them) the class one-hot over ``classes``
    and the mask-geometry features ``geo`` (N, n_geo)."""
    vec = norm.vector(centers, normal_xy)
    if cfg.n_classes:
        vec = np.hstack([vec, class_onehot(np.asarray(class_names), list(classes))])
    if cfg.n_geo:
        if geo is None or np.shape(geo) != (len(vec), cfg.n_geo):
            raise S2PError(f"this model needs ({len(vec)}, {cfg.n_geo}) mask-geometry "
                           f"features, got {None if geo is None else np.shape(geo)}")
        vec = np.hstack([vec, np.asarray(geo, np.float32)])
    return vec.astype(np.float32, copy=False)


# --------------------------------------------------------------------------------------------
# the network


class ConvBlock(nn.Sequential):
    """``n`` times (k x k convolution, 'same' padding, ReLU), optionally followed by 2x2 max-pool."""

    def __init__(self, c_in: int, c_out: int, k: int, n: int, pool: bool):
        layers: list[nn.Module] = []
        for i in range(n):
            layers += [nn.Conv2d(c_in if i == 0 else c_out, c_out, k, padding=k // 2), nn.ReLU()]
        if pool:
            layers.append(nn.MaxPool2d(2))
        super().__init__(*layers)


class Seg2PoseNet(nn.Module):
    """crops (B, 1, S, S) float in [0, 1], vec (B, n_vec + n_classes + n_geo) -> (B, 2)
    normalised residual in (-out_scale, out_scale)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        blocks, c = [], 1
        for c_out, k, pool in cfg.stages:
            blocks.append(ConvBlock(c, c_out, k, cfg.convs_per_block, pool))
            c = c_out
        self.trunk = nn.Sequential(*blocks)
        f = cfg.final_size
        if f < 1:
            raise ValueError(f"crop of {cfg.input_size} px is too small for {len(cfg.stages)} stages")
        self.head_conv = nn.Sequential(nn.Conv2d(c, cfg.head_channels, f), nn.ReLU())
        dense: list[nn.Module] = []
        d = cfg.head_channels + cfg.n_vec + cfg.n_classes + cfg.n_geo
        for _ in range(cfg.n_dense):
            dense += [nn.Linear(d, cfg.hidden), nn.ReLU()]
            d = cfg.hidden
        self.dense = nn.Sequential(*dense)
        self.out = nn.Linear(d, 2)

    def forward(self, crops: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
        x = self.head_conv(self.trunk(crops)).flatten(1)          # (B, head_channels)
        x = torch.cat([x, vec.to(x.dtype)], dim=1)                  # (B, head + 4 [+ cls, geo])
        return self.cfg.out_scale * torch.tanh(self.out(self.dense(x)).float())

    def n_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


def make_net(arch: str | NetConfig, n_classes: int = 0) -> Seg2PoseNet:
    cfg = arch if isinstance(arch, NetConfig) else NetConfig.named(arch, n_classes)
    return Seg2PoseNet(cfg)


def pick_device(device: str | None = None) -> torch.device:
    """'cuda' when available (or asked for), else the CPU."""
    if device:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def autocast(device: torch.device, enabled: bool = True):
    """bf16 autocast on CUDA only (on the CPU bf16 convolutions are slower than fp32 here)."""
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16,
                          enabled=enabled and device.type == "cuda")
