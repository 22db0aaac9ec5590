"""Exact sparse inference of Seg2PoseNet: compute the convolutions only where the mask is.

Why it is exact
---------------
A crop is one instance mask on zeros. With a zero input every activation of the trunk is the
same for every crop — the biases through the ReLUs, changed near the crop border only by the
zero padding. Call these the *background* activations (one dense forward pass of an all-zero
crop, ``Background``). A crop's activations differ from the background only inside the mask's
bounding box grown by the receptive field of the layer: a k x k convolution grows the changed
region by k // 2 on each side, a 2x2 max-pool maps it to the pooled cells it touches. So each
layer is computed on a *window* that contains the changed region: its input is the background,
with the previous layer's window pasted in and zeros beyond the map border (the 'same'
padding), and a 'valid' convolution of that gives exactly the dense output on the window.
Outside the window the dense output equals the background. Only the summation order of the
convolutions differs from the dense pass (differences of order 1e-7 in fp32).

Once a window covers most of its map (``dense_frac``) the rest of the trunk runs densely on the
full map (the window pasted into the background). Crops are grouped by window size (rounded up
to ``bucket`` pixels) so that one batch shares one window shape; a window may always be larger
than the changed region, that only costs time.

Training: the same forward is differentiable (slices, stacks and copies), and the background is
recomputed with autograd at every training forward (one all-zero crop per batch), so gradients
are exact too. In evaluation mode the background is cached and recomputed when any weight
changes (the tensors' version counters, bumped by every in-place optimiser step).

Shapes: crops (B, 1, S, S) float in [0, 1] (the network input, after any downsampling);
windows are (start, size) per axis in the coordinates of the layer's map.
"""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from seg2pose.method.net import Seg2PoseNet

# --------------------------------------------------------------------------------------------
# the trunk as a list of steps


@dataclass(frozen=True)
class Step:
    """One step of the trunk: ('conv', conv module, its 'same' padding) = convolution + ReLU,
    or ('pool', None, 0) = 2x2 max-pool (stride 2, floor). ``conv`` is set iff kind is 'conv'."""

    kind: str
    conv: nn.Conv2d | None = None
    pad: int = 0


def trunk_steps(net: Seg2PoseNet) -> list[Step]:
    """The trunk of ``net`` as steps; refuses layers whose sparse form is not implemented."""
    steps: list[Step] = []
    mods = [m for block in net.trunk for m in block.children()]
    i = 0
    while i < len(mods):
        m = mods[i]
        if isinstance(m, nn.Conv2d):
            k = m.kernel_size
            if (k[0] != k[1] or m.stride != (1, 1) or m.dilation != (1, 1) or m.groups != 1
                    or m.padding != (k[0] // 2, k[0] // 2) or k[0] % 2 == 0
                    or not isinstance(mods[i + 1], nn.ReLU)):
                raise ValueError(f"sparse inference needs odd 'same' convolutions + ReLU, got {m}")
            steps.append(Step("conv", m, k[0] // 2))
            i += 2
        elif isinstance(m, nn.MaxPool2d) and m.kernel_size in (2, (2, 2)) and m.stride in (2, (2, 2)) \
                and m.padding in (0, (0, 0)):
            steps.append(Step("pool"))
            i += 1
        else:
            raise ValueError(f"sparse inference does not know the layer {m}")
    return steps


def map_sizes(steps: list[Step], size: int) -> list[int]:
    """Side of the map after each step (input side ``size``)."""
    out = []
    for st in steps:
        size = size // 2 if st.kind == "pool" else size
        out.append(size)
    return out


# --------------------------------------------------------------------------------------------
# background activations


def _dense_step(st: Step, x: torch.Tensor) -> torch.Tensor:
    return F.relu(st.conv(x)) if st.conv is not None else F.max_pool2d(x, 2)


class Background:
    """The activations (C, H, W) after every step for an all-zero crop, each zero-padded by the
    next step's padding, so a window of the next step's input is one slice."""

    def __init__(self, net: Seg2PoseNet, steps: list[Step]):
        self.net, self.steps = net, steps
        self._key: tuple | None = None  # (size, device, dtype, weights) of ``padded``
        self.padded: list[torch.Tensor] = []

    def _weights_key(self) -> tuple[tuple[int, int], ...]:
        return tuple((p.data_ptr(), p._version) for p in self.net.parameters())

    def get(self, size: int, device, dtype, grad: bool) -> list[torch.Tensor]:
        """padded[i] = the input of step i (background), zero-padded by step i's padding."""
        key = (size, device, dtype, self._weights_key())
        if grad or key != self._key:
            x = torch.zeros(1, 1, size, size, device=device, dtype=dtype)
            padded = []
            with torch.set_grad_enabled(grad):
                for st in self.steps:
                    padded.append(F.pad(x[0], (st.pad,) * 4) if st.pad else x[0])
                    x = _dense_step(st, x)
                padded.append(x[0])  # the trunk's output
            if grad:
                return padded
            self.padded, self._key = padded, key
        return self.padded


# --------------------------------------------------------------------------------------------
# windows


def crop_boxes(x: np.ndarray | torch.Tensor) -> np.ndarray:
    """(B, 4) int [y0, y1, x0, x1) of the non-zero pixels of crops (B, [1,] S, S); an empty crop
    gets the 1x1 box at (0, 0) (any window is exact, the smallest is cheapest)."""
    a = x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)
    a = a.reshape(a.shape[0], a.shape[-2], a.shape[-1]) != 0
    rows, cols = a.any(axis=2), a.any(axis=1)
    out = np.zeros((len(a), 4), np.int64)
    for b in range(len(a)):
        r, c = np.flatnonzero(rows[b]), np.flatnonzero(cols[b])
        if len(r):
            out[b] = (r[0], r[-1] + 1, c[0], c[-1] + 1)
        else:
            out[b] = (0, 1, 0, 1)
    return out


def _place(lo: np.ndarray, size: int, n: int) -> np.ndarray:
    """Starts of windows of ``size`` that begin at ``lo`` where possible, kept inside [0, n)."""
    return np.clip(lo, 0, n - size)


def _gather(bg: torch.Tensor, pad: int, starts: np.ndarray, size: tuple[int, int],
            prev: torch.Tensor, prev_starts: np.ndarray) -> torch.Tensor:
    """Windows (B, C, h, w) of a step's input: the padded background ``bg`` (C, H + 2 pad,
    W + 2 pad) from map position ``starts`` (B, 2) - pad, with ``prev`` (B, C, hp, wp) — the
    previous step's windows at ``prev_starts`` (B, 2) in map coordinates — pasted where they
    overlap (a pool window may cut the odd last row/column that the pool drops)."""
    h, w = size
    hp, wp = prev.shape[-2:]
    out = []
    for b in range(len(starts)):
        sy, sx = int(starts[b, 0]), int(starts[b, 1])       # padded coords = map - pad + pad
        win = bg[:, sy:sy + h, sx:sx + w]
        py, px = int(prev_starts[b, 0]) + pad - sy, int(prev_starts[b, 1]) + pad - sx
        y0, x0 = max(py, 0), max(px, 0)
        y1, x1 = min(py + hp, h), min(px + wp, w)
        if (y0, x0, y1, x1) == (0, 0, h, w) and (py, px, hp, wp) == (0, 0, h, w):
            out.append(prev[b])
            continue
        win = win.clone()
        win[:, y0:y1, x0:x1] = prev[b, :, y0 - py:y1 - py, x0 - px:x1 - px]
        out.append(win)
    return torch.stack(out)


def window_sizes(boxes: np.ndarray, size: int, bucket: int) -> np.ndarray:
    """(B, 2) input window sides (h, w): the box sides rounded up to ``bucket``, at most ``size``."""
    hw = np.stack([boxes[:, 1] - boxes[:, 0], boxes[:, 3] - boxes[:, 2]], axis=1)
    return np.minimum(-(-hw // bucket) * bucket, size)


# --------------------------------------------------------------------------------------------
# the sparse forward


class SparseSeg2PoseNet(nn.Module):
    """Exact sparse forward of a Seg2PoseNet (paper, lite, lite-hr): the same output as
    ``net(crops, vec)`` to rounding. Shares ``net``'s parameters (no copy).

    ``bucket``: window sides are rounded up to this many input pixels, so that crops with
    similar masks share one batch; ``dense_frac``: a window covering this fraction of its map
    is widened to the whole map and the rest of the trunk runs densely (crops whose input
    window is that large run densely from the start, in one batch). Default: 0.6 for the
    paper arch, 0.25 for the small archs, where the per-window bookkeeping weighs more
    (docs/BENCHMARKS.md: lite-hr cars, windows of 0.3-0.7 of the crop, ran 0.7x sparse)."""

    def __init__(self, net: Seg2PoseNet, bucket: int = 8, dense_frac: float | None = None):
        super().__init__()
        self.net = net
        self.steps = trunk_steps(net)
        if dense_frac is None:
            dense_frac = 0.6 if net.cfg.input_size >= 300 else 0.25
        self.bucket, self.dense_frac = int(bucket), float(dense_frac)
        self.bg = Background(net, self.steps)

    # one batch whose windows share one input size ---------------------------------------------
    def backgrounds(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The padded background inputs of every step for crops like ``x`` (with autograd when
        training: the background depends on the weights)."""
        grad = torch.is_grad_enabled() and self.training
        return self.bg.get(x.shape[-1], x.device, x.dtype, grad)

    def trunk_windows(self, x: torch.Tensor, boxes: np.ndarray, hw: tuple[int, int],
                      bgs: list[torch.Tensor] | None = None) -> torch.Tensor:
        """Trunk output (B, C, f, f) for crops x (B, 1, S, S) whose non-zero pixels lie in
        ``boxes`` (B, 4), with input windows of sides ``hw`` (>= every box's sides)."""
        size = x.shape[-1]
        bgs = self.backgrounds(x) if bgs is None else bgs
        h, w = hw
        starts = np.stack([_place(boxes[:, 0], h, size), _place(boxes[:, 2], w, size)], axis=1)
        cur = torch.stack([x[b, :, starts[b, 0]:starts[b, 0] + h, starts[b, 1]:starts[b, 1] + w]
                           for b in range(len(x))])
        n = size
        for i, st in enumerate(self.steps):
            if (h, w) == (n, n):                      # the window is the whole map: go dense
                cur = _dense_step(st, cur)
                n = cur.shape[-1]
                h = w = n
                continue
            if st.conv is not None:
                p = st.pad
                nh, nw = min(h + 2 * p, n), min(w + 2 * p, n)
                if nh * nw >= self.dense_frac * n * n:
                    nh = nw = n
                lo = np.stack([_place(starts[:, 0] - p, nh, n), _place(starts[:, 1] - p, nw, n)], 1)
                inp = _gather(bgs[i], p, lo, (nh + 2 * p, nw + 2 * p), cur, starts)
                cur = F.relu(F.conv2d(inp, st.conv.weight, st.conv.bias))
            else:
                m = n // 2
                nh, nw = min(h // 2 + 1, m), min(w // 2 + 1, m)
                if nh * nw >= self.dense_frac * m * m:
                    nh = nw = m
                lo = np.stack([_place(starts[:, 0] // 2, nh, m), _place(starts[:, 1] // 2, nw, m)], 1)
                inp = _gather(bgs[i], 0, 2 * lo, (2 * nh, 2 * nw), cur, starts)
                cur = F.max_pool2d(inp, 2)
                n = m
            starts, h, w = lo, nh, nw
        if (h, w) != (n, n):                          # paste the last windows into the background
            full = np.zeros((len(x), 2), np.int64)
            cur = _gather(bgs[-1], 0, full, (n, n), cur, starts)
        return cur

    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        """Trunk output (B, C, f, f) of crops x (B, 1, S, S), windows grouped by size."""
        boxes = crop_boxes(x)
        hw = window_sizes(boxes, x.shape[-1], self.bucket)
        out: dict[int, torch.Tensor] = {}  # crop index -> its trunk output, every crop filled below
        keys = hw[:, 0] * 100000 + hw[:, 1]
        big = hw[:, 0] * hw[:, 1] >= self.dense_frac * x.shape[-1] ** 2
        bgs = self.backgrounds(x) if not big.all() else None
        if big.any():
            idx = np.flatnonzero(big)
            for j, y in zip(idx, self.net.trunk(x[idx])):
                out[int(j)] = y
            keys[big] = -1
        for k in np.unique(keys[~big]):
            idx = np.flatnonzero(keys == k)
            y = self.trunk_windows(x[idx], boxes[idx], (int(hw[idx[0], 0]), int(hw[idx[0], 1])), bgs)
            for j, b in enumerate(idx):
                out[int(b)] = y[j]
        return torch.stack([out[b] for b in range(len(x))])

    def forward(self, crops: torch.Tensor, vec: torch.Tensor) -> torch.Tensor:
        net = self.net
        x = net.head_conv(self.trunk(crops)).flatten(1)
        x = torch.cat([x, vec.to(x.dtype)], dim=1)
        return net.cfg.out_scale * torch.tanh(net.out(net.dense(x)).float())


def group_by_window(crops: np.ndarray, bucket: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Order (N,) that sorts crops (N, S, S) by input window (h, w), and the windows (N, 2), so
    consecutive batches hold similar windows (``SparseSeg2PoseNet.trunk`` groups within one
    batch; this groups across the batches)."""
    hw = window_sizes(crop_boxes(crops), crops.shape[-1], bucket)
    return np.lexsort((hw[:, 1], hw[:, 0])), hw


# --------------------------------------------------------------------------------------------
# the default CPU inference path


_ENABLED = os.environ.get("S2P_SPARSE", "1") != "0"
_WRAPPERS: weakref.WeakKeyDictionary[Seg2PoseNet, SparseSeg2PoseNet] = weakref.WeakKeyDictionary()


def set_enabled(on: bool) -> None:
    """Turn sparse inference on or off for this process (default on; environment S2P_SPARSE=0
    turns it off)."""
    global _ENABLED
    _ENABLED = bool(on)


def use_sparse(device: torch.device, sparse: bool | None = None) -> bool:
    """Whether inference on ``device`` takes the sparse path: asked for, or by default on the
    CPU (on a GPU a dense batch is already fast and the per-crop windows cost launches)."""
    return _ENABLED if sparse is None and torch.device(device).type == "cpu" else bool(sparse)


def sparse_of(net: Seg2PoseNet) -> SparseSeg2PoseNet:
    """The (cached) sparse wrapper of ``net``; its background follows the weights."""
    sp = _WRAPPERS.get(net)
    if sp is None:
        sp = _WRAPPERS[net] = SparseSeg2PoseNet(net)
    sp.train(net.training)
    return sp


@torch.no_grad()
def predict_inputs(net: Seg2PoseNet, x: np.ndarray, vec: np.ndarray, batch: int = 64,
                   device: torch.device | str = "cpu") -> np.ndarray:
    """Network outputs (N, 2) for network inputs x (N, S, S) float32 (after any downsampling)
    and vectors vec (N, n_vec...): crops sorted by window size, ``batch`` at a time."""
    sp = sparse_of(net)
    order, _ = group_by_window(x, sp.bucket)
    out = np.zeros((len(x), 2), np.float32)
    for s in range(0, len(x), batch):
        idx = order[s:s + batch]
        xb = torch.from_numpy(np.ascontiguousarray(x[idx]))[:, None].to(device)
        out[idx] = sp(xb, torch.from_numpy(vec[idx]).to(device)).float().cpu().numpy()
    return out
