"""Exact sparse inference (seg2pose/method/sparse.py): the sparse forward equals the dense network to
1e-5 in fp32 on random weights and real masks of every class (the synthetic renderer's road
users and rough models), masks cut by the image border, larger than the crop, empty crops, and
random boxes anywhere on crops of odd sizes; gradients equal too; the background follows the
weights; Checkpoint.predict takes the sparse path on the CPU by default and agrees with the
dense one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seg2pose.io.mots import read_mots
from seg2pose.io.scene import load_scene
from seg2pose.method import sparse
from seg2pose.method.checkpoint import Checkpoint
from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet, make_net
from seg2pose.method.sparse import SparseSeg2PoseNet, crop_boxes, sparse_of
from seg2pose.structures.masks import center_cut, crop_runs, downsample_crops, encode, mask_centers
from seg2pose.synth.generate import SynthOptions, generate_scene
from seg2pose.synth.rough import render_rough_examples

TOL = 1e-5


def he_init(net: Seg2PoseNet, seed: int = 0) -> Seg2PoseNet:
    """He-normal weights and positive biases: activations keep their scale through the trunk
    (PyTorch's default init shrinks them, which would make any sparse error invisible) and
    the all-zero background is not zero."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear)):
                fan_in = m.weight[0].numel()
                m.weight.copy_(torch.randn(m.weight.shape, generator=g) * (2 / fan_in) ** 0.5)
                m.bias.copy_(torch.rand(m.bias.shape, generator=g) * 0.1)
    return net.eval()


@pytest.fixture(scope="module")
def crops(tmp_path_factory) -> tuple[np.ndarray, list[str]]:
    """420 x 420 crops of real masks: the rendered road users of a 3-frame synthetic scene and
    rough models of every class, a mask cut by the image corner, one larger than the crop and
    an empty crop."""
    root = tmp_path_factory.mktemp("sparse")
    scene = load_scene(generate_scene(root / "s", SynthOptions(frames=3, seed=3, progress=False, workers=1,
                                      match="all")))
    cam = scene.cameras["c2"]
    h, w = cam.height, cam.width
    table = read_mots(scene.masks_path("c2"))
    rles, kinds = list(table.rles[:3]), ["scene"] * min(3, len(table))
    rng = np.random.default_rng(0)
    for cls in ("pedestrian", "bicyclist", "car"):
        r, _, _ = render_rough_examples(cam, scene.ground, cls, 2, rng, occlusion=0.5)
        rles += r
        kinds += [cls] * len(r)
    corner = np.zeros((h, w), np.uint8)
    corner[:90, :60] = 1                               # cut by the image's top-left corner
    big = np.zeros((h, w), np.uint8)
    big[100:650, 300:900] = 1                          # 550 x 600 px: larger than the crop
    big[300:320, 500:700] = 0
    rles += [encode(corner), encode(big)]
    kinds += ["corner", "big"]
    out = crop_runs(rles, h, w, mask_centers(rles, h, w))
    out = np.concatenate([out, np.zeros((1, 420, 420), np.uint8)])
    return out, kinds + ["empty"]


def dense_and_sparse(net: Seg2PoseNet, x: np.ndarray, seed: int = 0, dense_frac=None):
    xt = torch.from_numpy(np.asarray(x, np.float32))[:, None]
    v = torch.from_numpy(np.random.default_rng(seed).normal(size=(len(x), net.cfg.n_vec))
                         .astype(np.float32))
    with torch.no_grad():
        return net(xt, v), SparseSeg2PoseNet(net, dense_frac=dense_frac)(xt, v)


def test_crops_cover_the_cases(crops):
    x, kinds = crops
    box = crop_boxes(x)
    assert {"pedestrian", "bicyclist", "car", "scene"} <= set(kinds)
    corner, big = kinds.index("corner"), kinds.index("big")
    assert box[corner, 0] > 0 and box[corner, 2] > 0              # zero padding above / left
    assert tuple(box[big]) == (0, 420, 0, 420)                     # fills the crop
    assert not x[-1].any()


def test_paper_arch_sparse_equals_dense_on_real_masks(crops):
    x, kinds = crops
    sel = [kinds.index(k) for k in ("pedestrian", "bicyclist", "car", "corner", "big")]
    net = he_init(make_net("paper"))
    d, s = dense_and_sparse(net, x[sel])
    assert (d - s).abs().max().item() <= TOL
    assert d.std(dim=0).min().item() > 0.05        # the crops give different outputs


@pytest.mark.parametrize("arch", ["lite-hr", "lite"])
def test_small_archs_sparse_equals_dense_on_real_masks(arch, crops):
    x, _ = crops
    net = he_init(make_net(arch), seed=1)
    x = downsample_crops(center_cut(x, net.cfg.crop), net.cfg.downsample)
    d, s = dense_and_sparse(net, x, dense_frac=1.0)     # every crop through the windows
    assert (d - s).abs().max().item() <= TOL
    d, s = dense_and_sparse(net, x)                     # large windows run densely
    assert (d - s).abs().max().item() <= TOL
    assert d.std(dim=0).min().item() > 0.05


def narrow(size: int, pools: int) -> NetConfig:
    """The paper's structure (two 5x5 blocks, then 3x3 blocks with pooling) with 3 channels:
    the same windows as the paper arch at a fraction of the cost."""
    stages = ((3, 5, False), (3, 5, True), (3, 3, False)) + ((3, 3, True),) * pools
    return replace(NetConfig.paper(), crop=size, stages=stages, head_channels=4, hidden=8)


@settings(max_examples=12, deadline=None)
@given(size=st.integers(40, 90), pools=st.integers(0, 3), dense_frac=st.floats(0.2, 1.0),
       data=st.data())
def test_random_boxes_anywhere(size, pools, dense_frac, data):
    """Random blobs in random boxes (touching any border, or the whole crop), several per batch
    with different windows, on crop sides that pooling floors (odd sizes); windows switch to
    the dense path at any size."""
    net = he_init(Seg2PoseNet(narrow(size, pools)), seed=size)
    n = data.draw(st.integers(1, 4))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    x = np.zeros((n, size, size), np.float32)
    for b in range(n):
        y0, x0 = (data.draw(st.integers(0, size - 1)) for _ in range(2))
        y1, x1 = data.draw(st.integers(y0 + 1, size)), data.draw(st.integers(x0 + 1, size))
        x[b, y0:y1, x0:x1] = rng.random((y1 - y0, x1 - x0)) > 0.4
    d, s = dense_and_sparse(net, x, dense_frac=dense_frac)
    assert (d - s).abs().max().item() <= TOL


def test_one_pixel_at_the_window_edge_matters():
    """The output depends on a pixel one step outside a mask: a sparse pass that grew its
    windows too little would miss it, so the tolerance above is a real test."""
    net = he_init(Seg2PoseNet(narrow(64, 2)), seed=4)
    x = np.zeros((2, 64, 64), np.float32)
    x[:, 20:30, 20:30] = 1
    x[1, 30, 25] = 1
    d, s = dense_and_sparse(net, x)
    assert (d[0] - d[1]).abs().max().item() > 1e-3
    assert (d - s).abs().max().item() <= TOL


def test_gradients_equal_dense(crops):
    """Training through the sparse forward (background recomputed with autograd) gives the
    dense gradients of every weight."""
    x, _ = crops
    grads = []
    for sparse_fwd in (False, True):
        # float64: in float32 the two paths' convolution kernels (chosen by oneDNN per input
        # size and CPU) round differently, ~2e-4 of the largest gradient on some CPUs; the test
        # is about which terms enter the gradient, not about float32 rounding
        net = he_init(make_net("lite-hr"), seed=2).double().train()
        xt = torch.from_numpy(center_cut(x, 140).astype(np.float64))[:, None]
        v = torch.ones(len(x), 4, dtype=torch.float64)
        y = (SparseSeg2PoseNet(net, dense_frac=1.0).train() if sparse_fwd else net)(xt, v)
        (y ** 2).sum().backward()
        grads.append(torch.cat([p.grad.flatten() for p in net.parameters()]))
    scale = grads[0].abs().max().item()
    assert scale > 1e-3
    assert (grads[0] - grads[1]).abs().max().item() <= TOL * scale


def test_background_follows_the_weights():
    """A cached background is recomputed after an in-place optimiser step or a load."""
    net = he_init(Seg2PoseNet(narrow(48, 2)), seed=5)
    sp = sparse_of(net)
    x = torch.zeros(2, 1, 48, 48)
    x[0, 0, 5:9, 30:40] = 1
    x[1, 0, 40:48, 0:3] = 1
    v = torch.zeros(2, 4)
    with torch.no_grad():
        assert (sp(x, v) - net(x, v)).abs().max() <= TOL
        for p in net.parameters():
            p.add_(0.05)
        assert (sp(x, v) - net(x, v)).abs().max() <= TOL
        net.load_state_dict(he_init(Seg2PoseNet(narrow(48, 2)), seed=6).state_dict())
        assert (sp(x, v) - net(x, v)).abs().max() <= TOL
    assert sparse_of(net) is sp


def test_predict_is_sparse_on_the_cpu_and_equal(crops, monkeypatch):
    x, kinds = crops
    net = he_init(make_net(NetConfig.named("lite-hr")), seed=3)
    ck = Checkpoint(net, Normalisation(1280, 720), camera="c2", cls="car")
    cen = np.tile([[640.0, 360.0]], (len(x), 1))
    nxy = np.random.default_rng(0).normal(size=(len(x), 2))
    calls = []
    monkeypatch.setattr(SparseSeg2PoseNet, "trunk_windows",
                        lambda self, *a, _f=SparseSeg2PoseNet.trunk_windows: calls.append(1) or _f(self, *a))
    r_sparse = ck.predict(x, cen, nxy, batch=4)
    assert calls
    n = len(calls)
    r_dense = ck.predict(x, cen, nxy, batch=4, sparse=False)
    assert len(calls) == n
    np.testing.assert_allclose(r_sparse, r_dense, atol=TOL)
    sparse.set_enabled(False)
    try:
        assert not sparse.use_sparse(torch.device("cpu"))
        assert sparse.use_sparse(torch.device("cpu"), True)
    finally:
        sparse.set_enabled(True)
    assert sparse.use_sparse(torch.device("cpu")) and not sparse.use_sparse(torch.device("cuda"))
