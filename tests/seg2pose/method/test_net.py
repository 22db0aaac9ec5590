"""Seg2PoseNet: layer shapes as in Figure 3, the lite variant, normalisation, checkpoints."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from seg2pose.core.errors import InputError
from seg2pose.method.checkpoint import Checkpoint
from seg2pose.method.net import NetConfig, Normalisation, Seg2PoseNet, make_net
from seg2pose.structures.masks import downsample_crops


def _shapes(net: Seg2PoseNet, size: int, n_vec: int) -> dict[str, list[tuple]]:
    """Output shapes (without batch) of every conv block, pool, dense layer, in order."""
    seen: dict[str, list[tuple]] = {"conv": [], "pool": [], "relu_dense": [], "out": []}
    hooks = []
    for blk in net.trunk:
        for m in blk:
            if isinstance(m, nn.Conv2d):
                hooks.append(m.register_forward_hook(
                    lambda m, i, o: seen["conv"].append(tuple(o.shape[1:]))))
            if isinstance(m, nn.MaxPool2d):
                hooks.append(m.register_forward_hook(
                    lambda m, i, o: seen["pool"].append(tuple(o.shape[1:]))))
    def head_hook(m, i, o):
        seen["head"] = tuple(o.shape[1:])  # (a hook returning a value would replace the output)

    hooks.append(net.head_conv.register_forward_hook(head_hook))
    for m in net.dense:
        if isinstance(m, nn.Linear):
            hooks.append(m.register_forward_hook(
                lambda m, i, o: seen["relu_dense"].append((tuple(i[0].shape[1:]), tuple(o.shape[1:])))))
    hooks.append(net.out.register_forward_hook(lambda m, i, o: seen["out"].append(tuple(o.shape[1:]))))
    with torch.no_grad():
        y = net(torch.zeros(1, 1, size, size), torch.zeros(1, n_vec))
    for h in hooks:
        h.remove()
    seen["y"] = tuple(y.shape)
    return seen


def test_paper_arch_shapes_figure3():
    net = make_net("paper")
    s = _shapes(net, 420, 4)
    # two convolutions per block; the block outputs of Figure 3
    assert s["conv"][1] == (11, 420, 420) and s["conv"][3] == (21, 420, 420)
    assert s["conv"][5] == (31, 210, 210)
    assert s["conv"][0::2] == s["conv"][1::2]  # both convs of a block have the block's shape
    assert s["pool"] == [(21, 210, 210), (39, 105, 105), (47, 52, 52), (55, 26, 26),
                         (63, 13, 13), (71, 6, 6)]
    assert s["head"] == (71, 1, 1)
    assert s["relu_dense"] == [((75,), (148,)), ((148,), (148,)), ((148,), (148,))]
    assert s["out"] == [(2,)] and s["y"] == (1, 2)
    kernels = [m.kernel_size for blk in net.trunk for m in blk if isinstance(m, nn.Conv2d)]
    assert kernels[:4] == [(5, 5)] * 4 and set(kernels[4:]) == {(3, 3)}
    assert net.head_conv[0].kernel_size == (6, 6)


def test_lite_shapes_and_output_range():
    net = make_net("lite")
    assert net.cfg.input_size == 140 and net.cfg.final_size == 4
    s = _shapes(net, 140, 4)
    assert s["pool"] == [(8, 70, 70), (16, 35, 35), (24, 17, 17), (32, 8, 8), (48, 4, 4)]
    assert s["head"] == (64, 1, 1)
    assert s["relu_dense"][0] == ((68,), (64,))
    # the 2.5 tanh output bound holds even for wild inputs
    torch.manual_seed(0)
    with torch.no_grad():
        y = net(torch.rand(4, 1, 140, 140) * 100, torch.randn(4, 4) * 100)
    assert y.shape == (4, 2) and float(y.abs().max()) <= 2.5
    shared = make_net("lite", n_classes=3)
    assert _shapes(shared, 140, 7)["relu_dense"][0] == ((71,), (64,))


def test_normalisation_vector_hand_values():
    pts = np.array([[0.0, 0, 0], [20, 0, 0], [0, 10, 0], [20, 10, 0]])
    n = Normalisation.for_scene(pts, width=200, height=100)
    assert n.center_xy == (10.0, 5.0) and n.scale == 10.0
    v = n.vector(np.array([[100.0, 25.0], [0.0, 100.0]]), np.array([[10.0, 5.0], [30.0, -5.0]]))
    np.testing.assert_allclose(v, [[0, -0.5, 0, 0], [-1, 1, 2, -1]])


def test_downsample_is_block_fraction():
    c = np.zeros((1, 6, 6), np.uint8)
    c[0, :3, :3] = 1
    c[0, 3, 3] = 1
    d = downsample_crops(c, 3)
    np.testing.assert_allclose(d[0], [[1, 0], [0, 1 / 9]])


def test_checkpoint_round_trip_and_mismatch(tmp_path):
    torch.manual_seed(3)
    net = make_net("lite", n_classes=3)
    norm = Normalisation(width=320, height=240, center_xy=(1.0, 2.0), scale=12.0, residual_scale=0.5)
    ck = Checkpoint(net, norm, camera="c1", cls="*", scene_fingerprint="abc",
                    classes=["pedestrian", "bicyclist", "car"], info={"val_loss": 0.12, "epoch": 7})
    path = tmp_path / "c1__all.safetensors"
    ck.save(path)
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["arch"] == "lite" and meta["camera"] == "c1" and meta["val_loss"] == 0.12
    back = Checkpoint.load(path, arch="lite", camera="c1")
    assert back.norm == norm and back.classes == ck.classes and back.info["epoch"] == 7
    for (k, a), (k2, b) in zip(net.state_dict().items(), back.net.state_dict().items()):
        assert k == k2 and torch.equal(a, b)
    # predict on full-resolution crops: same numbers from the original and the loaded model
    rng = np.random.default_rng(0)
    crops = (rng.random((3, 420, 420)) > 0.7).astype(np.uint8)
    cen = np.array([[10.0, 20], [100, 100], [300, 200]])
    nxy = np.array([[0.0, 0], [5, 5], [-3, 8]])
    names = np.array(["car", "pedestrian", "bicyclist"], object)
    r1 = ck.predict(crops, cen, nxy, names)
    r2 = back.predict(crops, cen, nxy, names)
    np.testing.assert_allclose(r1, r2, atol=1e-6)
    assert np.abs(r1).max() <= 2.5 * 0.5
    with pytest.raises(InputError, match="arch 'lite', expected 'paper'"):
        Checkpoint.load(path, arch="paper")
    with pytest.raises(InputError, match="camera 'c1', expected 'c2'"):
        Checkpoint.load(path, camera="c2")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    with pytest.raises(InputError, match="safetensors"):
        Checkpoint.load(bad)
    with pytest.raises(InputError, match="not found"):
        Checkpoint.load(tmp_path / "none.safetensors")


def test_weights_of_other_arch_are_refused(tmp_path):
    from safetensors.torch import save_file

    lite = make_net("lite")
    ck = Checkpoint(lite, Normalisation(100, 100), camera="c0", cls="car")
    path = tmp_path / "x.safetensors"
    ck.save(path)
    # metadata claims paper, weights are lite: the load names the mismatch instead of crashing
    meta = ck.metadata()
    meta["net"] = NetConfig.paper().to_dict()
    meta["arch"] = "paper"
    save_file({k: v.contiguous() for k, v in lite.state_dict().items()}, str(path),
              metadata={"s2p": json.dumps(meta)})
    with pytest.raises(InputError, match="do not fit arch 'paper'"):
        Checkpoint.load(path)


def test_radial_offset_is_subtracted_along_the_viewing_direction():
    torch.manual_seed(0)
    ck = Checkpoint(make_net("lite"), Normalisation(320, 240), camera="c0", cls="car")
    crops = np.zeros((2, 420, 420), np.uint8)
    crops[:, 200:220, 190:230] = 1
    cen = np.array([[100.0, 100], [200, 150]])
    nxy = np.array([[10.0, 0], [0, -20]])
    names = np.array(["car", "car"], object)
    plain = ck.predict(crops, cen, nxy, names, origin_xy=np.zeros(2))
    ck.info["radial_offset"] = {"car": 0.25}
    cal = ck.predict(crops, cen, nxy, names, origin_xy=np.zeros(2))
    np.testing.assert_allclose(plain - cal, [[0.25, 0], [0, -0.25]], atol=1e-6)


def test_lite_hr_shapes_and_centre_cut_of_pipeline_crops():
    """lite-hr: the lite trunk on a full-resolution 140x140 crop; Checkpoint.predict cuts it
    from the centre of the pipeline's 420 crops, which equals cropping at 140 directly."""
    from seg2pose.structures.masks import center_cut, crop_runs, encode, mask_centers

    net = make_net("lite-hr", n_classes=3)
    assert net.cfg.arch == "lite-hr" and net.cfg.crop == 140 and net.cfg.downsample == 1
    assert net.cfg.input_size == 140 and net.cfg.final_size == 4
    assert make_net("lite").n_params() + 3 * 64 == net.n_params()  # same trunk (+ class inputs)
    s = _shapes(net, 140, 7)
    assert s["pool"] == [(8, 70, 70), (16, 35, 35), (24, 17, 17), (32, 8, 8), (48, 4, 4)]
    assert s["head"] == (64, 1, 1) and s["relu_dense"][0] == ((71,), (64,)) and s["y"] == (1, 2)
    # centre cut of 420 crops == 140 crops at the same (non-integer) centres, incl. image borders
    h, w = 120, 200
    masks = np.zeros((3, h, w), np.uint8)
    masks[0, 30:70, 50:61] = 1
    masks[1, 0:119, 150:200] = 1          # touches the border, taller than half the crop
    masks[2, 5:8, 3:4] = 1
    rles = [encode(m) for m in masks]
    cen = mask_centers(rles, h, w, "bbox") + np.array([[0.3, -0.2], [0.5, 0.5], [-0.4, 0.0]])
    big = crop_runs(rles, h, w, cen, size=420)
    np.testing.assert_array_equal(center_cut(big, 140), crop_runs(rles, h, w, cen, size=140))
    ck = Checkpoint(net, Normalisation(w, h), camera="c0", cls="*",
                    classes=["pedestrian", "bicyclist", "car"])
    names = np.array(["pedestrian", "car", "bicyclist"], object)
    nxy = np.zeros((3, 2))
    np.testing.assert_allclose(ck.predict(big, cen, nxy, names),
                               ck.predict(center_cut(big, 140), cen, nxy, names), atol=1e-6)
    with pytest.raises(ValueError):
        center_cut(big[:, :139, :139], 140)
