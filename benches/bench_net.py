"""Seg2PoseNet throughput: crops/s for inference and training, both archs, fp32 and bf16, on
the CPU and (when present) on CUDA. Also the crop pipeline (RLE decode + 420x420 crop +
downsample) that feeds the network, and peak memory.

    .venv/bin/python benches/bench_net.py [--quick] [--threads 2] [--arch lite,paper]

Throughput is measured after warm-up over a fixed wall-clock budget per cell; the training
step is forward + backward + Adam step at the given batch size.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch

from seg2pose.net import make_net


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
    from seg2pose.masks import crop_runs
    from seg2pose.masks import crop_masks, encode, mask_centers
    from seg2pose.masks import downsample_crops

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
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
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
