"""Seg2PoseNet throughput: crops/s for inference and training, both archs, fp32 and bf16, on
the CPU and (when present) on CUDA. Also the crop pipeline (RLE decode + 420x420 crop +
downsample) that feeds the network, and peak memory.

    .venv/bin/python benches/bench_net.py [--quick] [--threads 2] [--arch lite,paper]
    .venv/bin/python benches/bench_net.py --sparse --arch paper,lite-hr [--scene DIR]

Throughput is measured after warm-up over a fixed wall-clock budget per cell; the training
step is forward + backward + Adam step at the given batch size.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from seg2pose.method.net import make_net


def _timeit(fn, budget_s: float, min_iters: int = 2) -> float:
    """Seconds per call: warm-up once, then as many calls as fit in ``budget_s``."""
    fn()
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    n, t0 = 0, time.perf_counter()
    while n < min_iters or time.perf_counter() - t0 < budget_s:
        fn()
        n += 1
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    return (time.perf_counter() - t0) / n


def bench_cell(arch: str, device: torch.device, dtype: str, batch: int, train: bool,
               budget: float, compile_net: bool = False) -> float:
    torch.manual_seed(0)
    net = make_net(arch).to(device)
    s = net.cfg.input_size
    x = (torch.rand(batch, 1, s, s, device=device) > 0.8).float()
    v = torch.randn(batch, 4, device=device)
    y = torch.randn(batch, 2, device=device)
    if device.type == "cuda":
        net = net.to(memory_format=torch.channels_last)
        x = x.to(memory_format=torch.channels_last)
    ac = torch.autocast(device.type, dtype=torch.bfloat16, enabled=dtype == "bf16")
    if compile_net:  # fuses the ReLUs/pools into the convolutions' epilogues (GPU: max-autotune)
        net = torch.compile(net, mode="max-autotune" if device.type == "cuda" else "default")
    if train:
        opt = torch.optim.Adam(net.parameters(), lr=5e-5)
        net.train()

        def step():
            with ac:
                p = net(x, v)
            loss = ((p.float() - y) ** 2).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
    else:
        net.eval()

        def step():
            with torch.no_grad(), ac:
                net(x, v)
    return batch / _timeit(step, budget)


def bench_crops(n: int = 256, runs: bool = True) -> float:
    """Crops/s of the input path: RLE -> 420x420 crop around the bbox centre -> downsample /3.
    runs=True: crops straight from the RLE runs (masks.crop_runs, what the pipeline uses);
    False: full-image decode with pycocotools, then slicing (masks.crop_masks)."""
    from seg2pose.structures.masks import crop_masks, crop_runs, downsample_crops, encode, mask_centers

    rng = np.random.default_rng(0)
    h, w = 720, 1280
    rles = []
    for _ in range(n):
        m = np.zeros((h, w), np.uint8)
        x0, y0 = rng.integers(0, w - 200), rng.integers(0, h - 150)
        m[y0:y0 + rng.integers(20, 150), x0:x0 + rng.integers(10, 200)] = 1
        rles.append(encode(m))
    t0 = time.perf_counter()
    for s in range(0, n, 64):
        r = rles[s:s + 64]
        c = (crop_runs if runs else crop_masks)(r, h, w, mask_centers(r, h, w))
        downsample_crops(c, 3)
    return n / (time.perf_counter() - t0)


def scene_crops(scene_dir: str | None, per_class: int, seed: int = 0):
    """Real crops of a synthetic scene: up to ``per_class`` test-split masks per class drawn
    from all cameras -> (crops (N, 420, 420) uint8, class names (N,), the scene folder, each
    class's share of all the split's masks). Without a scene folder
    a small scene (3 x 120 frames) is generated in a temporary folder."""
    import tempfile
    from pathlib import Path

    from seg2pose.geometry.normal import DEFAULT_CENTER_METHOD
    from seg2pose.io.mots import iter_mots
    from seg2pose.io.scene import load_scene
    from seg2pose.structures.masks import crop_runs, mask_centers

    if scene_dir is None:
        from seg2pose.synth.generate import SynthOptions, generate_scene
        scene_dir = str(Path(tempfile.mkdtemp(prefix="s2p_bench_net_")) / "scene")
        generate_scene(Path(scene_dir), SynthOptions(frames=120, seed=seed, progress=False))
    scene = load_scene(scene_dir)
    by_id = {c.id: c.name for c in scene.classes}
    rles, names, hw = [], [], []
    for cam in scene.cameras:
        for _, t in iter_mots(scene.masks_path(cam), frame_range=scene.split_range("test")):
            for r, c in zip(t.rles, t.class_id):
                rles.append(r)
                names.append(by_id.get(int(c), ""))
                hw.append((t.height, t.width))
    names = np.array(names, object)
    share = {c: float(np.mean(names == c)) for c in sorted(set(names) - {""})}
    print("class shares of the scene's test-split masks: "
          + ", ".join(f"{c} {v:.0%}" for c, v in share.items()))
    rng = np.random.default_rng(seed)
    pick = np.concatenate([rng.permutation(np.flatnonzero(names == c))[:per_class]
                           for c in sorted(set(names) - {""})])
    crops = np.concatenate([crop_runs([rles[i]], *hw[i], mask_centers([rles[i]], *hw[i],
                                                                      DEFAULT_CENTER_METHOD))
                            for i in pick])
    return crops, names[pick], scene_dir, share


def _random_net(arch: str, seed: int = 0):
    """A net with He-initialised weights and small positive biases, so that activations keep
    their scale through the trunk (the default init shrinks them) and the background is not
    zero."""
    torch.manual_seed(seed)
    net = make_net(arch)
    for m in net.modules():
        if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear)):
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
            torch.nn.init.uniform_(m.bias, 0.0, 0.1)
    return net.eval()


def bench_sparse(crops: np.ndarray, names: np.ndarray, arch: str, batch: int,
                 train_batch: int, reps: int = 2, share: dict | None = None,
                 clock=time.perf_counter) -> None:
    """Dense vs exact sparse inference (and training) on the same real crops: crops/s per
    class, the speed-up, max |dense - sparse|, and the distribution of window sizes.
    ``clock``: time.perf_counter (wall) or time.process_time (this process's CPU seconds:
    steadier on a shared machine with one torch thread)."""
    from seg2pose.method.sparse import crop_boxes, sparse_of, window_sizes
    from seg2pose.structures.masks import center_cut, downsample_crops

    net = _random_net(arch)
    sp = sparse_of(net)
    x = downsample_crops(center_cut(crops, net.cfg.crop), net.cfg.downsample)
    vec = np.random.default_rng(1).normal(size=(len(x), 4)).astype(np.float32)
    hw = window_sizes(crop_boxes(x), x.shape[-1], sp.bucket)
    frac = hw[:, 0] * hw[:, 1] / x.shape[-1] ** 2
    q = np.percentile(frac, [10, 50, 90, 100])
    print(f"\n{arch}: {len(x)} real crops ({x.shape[-1]} px network input), window area / crop "
          f"area: p10 {q[0]:.3f}, median {q[1]:.3f}, p90 {q[2]:.3f}, max {q[3]:.3f}; "
          f"{(frac >= 0.99).mean():.0%} of windows are the whole crop")
    print(f"{'class':<11} {'n':>4} {'median window':>14} {'dense crops/s':>14} {'sparse crops/s':>15} "
          f"{'speed-up':>9} {'max |diff|':>11}")
    rows = [(c, names == c) for c in sorted(set(names))] + [("all", np.ones(len(x), bool))]
    per_crop = {}
    for cls, sel in rows:
        xs, vs = torch.from_numpy(x[sel])[:, None], torch.from_numpy(vec[sel])
        order = np.argsort(frac[sel], kind="stable")   # as predict_inputs sorts them
        xs, vs = xs[order], vs[order]
        td, ts = [], []   # best of ``reps`` passes, dense and sparse interleaved (shared CPU)
        with torch.no_grad():
            for _ in range(reps):
                t0 = clock()
                d = torch.cat([net(xs[s:s + batch], vs[s:s + batch]) for s in range(0, len(xs), batch)])
                t1 = clock()
                q_ = torch.cat([sp(xs[s:s + batch], vs[s:s + batch]) for s in range(0, len(xs), batch)])
                t2 = clock()
                td.append(t1 - t0)
                ts.append(t2 - t1)
        mh = np.median(hw[sel], axis=0).astype(int)
        print(f"{cls:<11} {int(sel.sum()):>4} {f'{mh[0]}x{mh[1]}':>14} {len(xs) / min(td):>14.1f} "
              f"{len(xs) / min(ts):>15.1f} {min(td) / min(ts):>8.1f}x "
              f"{(d - q_).abs().max().item():>11.2e}", flush=True)
        per_crop[cls] = (min(td) / len(xs), min(ts) / len(xs))
    if share:   # seconds per crop weighted by how often each class occurs in the scene
        td = sum(w * per_crop[c][0] for c, w in share.items() if c in per_crop)
        ts = sum(w * per_crop[c][1] for c, w in share.items() if c in per_crop)
        print(f"{'scene mix':<11} {'':>4} {'':>14} {1 / td:>14.1f} {1 / ts:>15.1f} {td / ts:>8.1f}x"
              "   (per-class times weighted by the scene's class shares)")
    # training: forward + backward + Adam step, dense vs sparse, on the same batches
    xs, vs = torch.from_numpy(x)[:, None], torch.from_numpy(vec)
    y = torch.randn(len(xs), 2)
    times, grads = {}, {}
    for mode in ("dense", "sparse"):
        tnet = _random_net(arch)
        tnet.train()
        fwd = tnet if mode == "dense" else sparse_of(tnet)
        opt = torch.optim.Adam(tnet.parameters(), lr=1e-4)
        t0 = clock()
        for k, s in enumerate(range(0, len(xs), train_batch)):
            loss = ((fwd(xs[s:s + train_batch], vs[s:s + train_batch]) - y[s:s + train_batch]) ** 2).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if k == 0:
                grads[mode] = torch.cat([p.grad.flatten() for p in tnet.parameters()])
            opt.step()
        times[mode] = clock() - t0
    gdiff = ((grads["dense"] - grads["sparse"]).abs().max() / grads["dense"].abs().max()).item()
    print(f"training (batch {train_batch}, forward + backward + Adam, random batches of these crops): "
          f"dense {len(xs) / times['dense']:.1f} crops/s, sparse {len(xs) / times['sparse']:.1f} "
          f"crops/s ({times['dense'] / times['sparse']:.1f}x); first-step gradients max relative "
          f"difference {gdiff:.1e}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="short budgets (about 1 minute on a CPU)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--arch", default="lite,lite-hr,paper")
    ap.add_argument("--compile", action="store_true", help="torch.compile the network first "
                    "(the warm-up is excluded from the timing)")
    ap.add_argument("--batch", type=int, default=None,
                    help="inference batch (default: 64 lite / 4 paper on the CPU; 256 / 64 on CUDA)")
    ap.add_argument("--device", default=None, help="cpu, cuda or both (default: both if CUDA)")
    ap.add_argument("--sparse", action="store_true",
                    help="only dense vs exact sparse inference and training on a scene's real crops")
    ap.add_argument("--scene", default=None, help="scene folder for --sparse (default: generate a "
                    "small one in a temporary folder)")
    ap.add_argument("--per-class", type=int, default=24, help="crops per class for --sparse")
    ap.add_argument("--reps", type=int, default=2, help="--sparse: best of this many passes")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="--sparse: wall-clock seconds, or this process's CPU seconds (steadier "
                         "on a shared machine; use with --threads 1)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.sparse:
        crops, names, where, share = scene_crops(args.scene, args.per_class)
        print(f"torch {torch.__version__}, CPU threads {torch.get_num_threads()}, crops from {where} "
              f"(test split, all cameras); crops per {args.clock} second")
        clock = time.process_time if args.clock == "cpu" else time.perf_counter
        for arch in args.arch.split(","):
            small = arch != "paper"
            bench_sparse(crops, names, arch, args.batch or (64 if small else 8), 16 if small else 8,
                         args.reps, share, clock)
        return
    devices = [torch.device("cpu")]
    if torch.cuda.is_available() and args.device != "cpu":
        devices = [torch.device("cuda")] if args.device == "cuda" else devices + [torch.device("cuda")]
        torch.backends.cudnn.benchmark = True
    budget = 1.0 if args.quick else 3.0
    print(f"torch {torch.__version__}, CPU threads {torch.get_num_threads()}")
    print(f"input path (RLE -> 420x420 crop -> downsample /3), 1280x720 masks: "
          f"{bench_crops(runs=True):.0f} crops/s from RLE runs, "
          f"{bench_crops(runs=False):.0f} crops/s with a full pycocotools decode")
    print(f"{'device':<28} {'arch':<7} {'dtype':<5} {'batch':>5} {'infer crops/s':>14} {'train crops/s':>14}")
    for dev in devices:
        name = "cpu" if dev.type == "cpu" else f"cuda ({torch.cuda.get_device_name(dev)})"
        for arch in args.arch.split(","):
            for dtype in ("fp32", "bf16"):
                small = arch != "paper"
                if dev.type == "cpu":
                    batch, tbatch = (64, 16) if small else (4, 4)
                    b = budget if small else budget / 2
                else:
                    batch, tbatch, b = 64 if arch == "paper" else 256, 16 if arch == "paper" else 64, budget
                batch = args.batch or batch
                inf = bench_cell(arch, dev, dtype, batch, False, b, args.compile)
                trn = bench_cell(arch, dev, dtype, tbatch, True, b, args.compile)
                print(f"{name:<28} {arch:<7} {dtype:<5} {batch:>5} {inf:>14.1f} {trn:>14.1f}"
                      f"   (train batch {tbatch})", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {peak:.0f} MB")
    if torch.cuda.is_available():
        print(f"peak CUDA memory {torch.cuda.max_memory_allocated() / 2**20:.0f} MB")


if __name__ == "__main__":
    main()
