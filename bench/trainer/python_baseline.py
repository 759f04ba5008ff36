#!/usr/bin/env python3
"""The thesis's own stack, for comparison: the same denoiser, loss and
optimiser step as dofarm-train, written in Python with Debian's python3-torch,
and the same data pipeline (7-frame 64x64 crops read from a dofarm shard with
python3-h5py, demodulated, log1p, depth and CoC transforms, random crop,
rotation, reversal). Prints the median milliseconds of one training step and
of one batch of the data pipeline, so bench/trainer/python_vs_cpp.sh can
compare them with bench/trainer/trainer_speed and data_stream on one machine.
With --loop N it also runs N steps of a plain synchronous training loop (an
h5py batch, then the step, as a Python training script without a DataLoader
does) and prints the mean milliseconds per step. --channels-last converts the
model and its inputs to torch.channels_last (NHWC), which dofarm-train does on
the CPU; without it the model is PyTorch's default NCHW. Never asserts.

    python_baseline.py [--shard SHARD.h5] [--reps 5] [--loop N] [--channels-last]
"""
import argparse
import math
import statistics
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

WIDTHS_DOF = [36, 48, 64, 85, 113]  # thesis 4.2, with the CoC input
IN_CHANNELS_DOF = 12                # radiance 3, albedo 3, normal 3, depth, roughness, CoC


class Denoiser(nn.Module):
    """Thesis 4.2: 5 encoder blocks of three 3x3 convs + 2x2 max-pool, a
    bottleneck of two convs, 5 decoder blocks (nearest x2, skip concat, two
    convs), LeakyReLU 0.1, a linear 3x3 output conv."""

    def __init__(self, widths=WIDTHS_DOF, cin=IN_CHANNELS_DOF):
        super().__init__()
        self.enc = nn.ModuleList()
        c = cin
        for w in widths:
            self.enc.append(nn.ModuleList([nn.Conv2d(c, w, 3, padding=1),
                                           nn.Conv2d(w, w, 3, padding=1),
                                           nn.Conv2d(w, w, 3, padding=1)]))
            c = w
        self.mid = nn.ModuleList([nn.Conv2d(c, c, 3, padding=1), nn.Conv2d(c, c, 3, padding=1)])
        self.dec = nn.ModuleList()
        for w in reversed(widths):
            self.dec.append(nn.ModuleList([nn.Conv2d(c + w, w, 3, padding=1),
                                           nn.Conv2d(w, w, 3, padding=1)]))
            c = w
        self.out = nn.Conv2d(c, 3, 3, padding=1)

    def forward(self, x):
        skips = []
        for block in self.enc:
            for conv in block:
                x = F.leaky_relu(conv(x), 0.1)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        for conv in self.mid:
            x = F.leaky_relu(conv(x), 0.1)
        for block, skip in zip(self.dec, reversed(skips)):
            x = torch.cat([F.interpolate(x, scale_factor=2, mode="nearest"), skip], 1)
            for conv in block:
                x = F.leaky_relu(conv(x), 0.1)
        return self.out(x)


def log_kernel(sigma=1.5):
    """Laplacian of Gaussian (thesis eq. 4.3), zero sum, unit L1 norm."""
    r = int(math.ceil(3 * sigma))
    ax = torch.arange(-r, r + 1, dtype=torch.float64)
    q = (ax[None, :] ** 2 + ax[:, None] ** 2) / (2 * sigma * sigma)
    k = (q - 1) * torch.exp(-q)
    k -= k.mean()
    k /= k.abs().sum()
    return k.float()


def loss_fn(out, target, kernel):
    """0.8 L1 + 0.2 L1 of LoG-filtered images (thesis eq. 4.2-4.4)."""
    c = out.shape[1]
    w = kernel[None, None].expand(c, 1, *kernel.shape)
    log = (F.conv2d(out, w, groups=c) - F.conv2d(target, w, groups=c)).abs().mean()
    return 0.8 * (out - target).abs().mean() + 0.2 * log


def median_ms(fn, reps):
    fn()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3, min(times) * 1e3


def data_batch(f, rng, eps=1e-3, crop=64, seq=7, batch=4):
    """One batch of the augmentation pipeline (thesis 4.3.3) from a shard."""
    noisy, albedo = f["noisy"], f["albedo_ref"]
    normal, depth, rough, coc, ref = f["normal"], f["depth"], f["roughness"], f["coc"], f["reference"]
    cam = f["camera"][:]
    n_frames, versions, _, h, w = noisy.shape
    xs, ys = [], []
    for _ in range(batch):
        f0 = int(rng.integers(0, n_frames - seq + 1))
        y0, x0 = int(rng.integers(0, h - crop + 1)), int(rng.integers(0, w - crop + 1))
        frames, shown = [f0], {f0: 0}
        for _ in range(seq - 1):  # the camera "stops" with p = 0.25
            prev = frames[-1]
            frames.append(prev if rng.random() < 0.25 else prev + 1)
        frames = [min(fr, f0 + seq - 1) for fr in frames]
        if rng.random() < 0.5:
            frames.reverse()
        rot = int(rng.integers(0, 4))
        xin, yt = [], []
        for fr in frames:
            v = shown.get(fr, -1) + 1
            shown[fr] = v
            sl = (slice(y0, y0 + crop), slice(x0, x0 + crop))
            a = torch.from_numpy(albedo[fr, :, sl[0], sl[1]])
            rad = torch.from_numpy(noisy[fr, v % versions, :, sl[0], sl[1]])
            z = torch.from_numpy(depth[fr, :, sl[0], sl[1]])
            fd = float(cam[fr, 10])
            zn = torch.where(z > 0, z / (z + fd), torch.ones_like(z))
            c = torch.log1p(torch.from_numpy(coc[fr, :, sl[0], sl[1]])) / math.log(33.0)
            x = torch.cat([torch.log1p(rad.clamp(min=0) / (a + eps)), a,
                           torch.from_numpy(normal[fr, :, sl[0], sl[1]]), zn,
                           torch.from_numpy(rough[fr, :, sl[0], sl[1]]), c], 0)
            t = torch.log1p(torch.from_numpy(ref[fr, :, sl[0], sl[1]]).clamp(min=0) / (a + eps))
            xin.append(torch.rot90(x, rot, (1, 2)))
            yt.append(torch.rot90(t, rot, (1, 2)))
        xs.append(torch.stack(xin))
        ys.append(torch.stack(yt))
    return torch.stack(xs), torch.stack(ys)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shard", help="a dofarm shard (>= 7 frames, >= 64x64) for the data pipeline")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--loop", type=int, default=0, help="steps of the full loop (needs --shard)")
    ap.add_argument("--channels-last", action="store_true")
    args = ap.parse_args()
    fmt = torch.channels_last if args.channels_last else torch.contiguous_format
    torch.manual_seed(0)
    model = Denoiser().to(memory_format=fmt)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4, betas=(0.9, 0.99))
    kernel = log_kernel()  # sigma 1.5, dofarm-train's loss.log_sigma default
    x = torch.rand(4, 7, IN_CHANNELS_DOF, 64, 64)
    t = torch.rand(4, 7, 3, 64, 64)

    def step(x, t):
        opt.zero_grad()
        out = model(x.reshape(28, IN_CHANNELS_DOF, 64, 64).contiguous(memory_format=fmt))
        loss_fn(out, t.reshape(28, 3, 64, 64).contiguous(memory_format=fmt), kernel).backward()
        opt.step()

    name = "NHWC" if args.channels_last else "NCHW"
    print(f"python {torch.__version__}, {torch.get_num_threads()} intra-op threads, {name}, median of {args.reps}")
    med, best = median_ms(lambda: step(x, t), args.reps)
    print(f"python train step ms (DOF, 4 x 7 x 64^2): {med:.1f} (min {best:.1f})")
    if args.shard:
        import h5py
        import numpy as np
        rng = np.random.default_rng(1)
        with h5py.File(args.shard, "r") as f:
            ms, _ = median_ms(lambda: data_batch(f, rng), args.reps)
            print(f"python data batch ms (4 sequences x 7 frames): {ms:.1f}  ({4000.0 / ms:.1f} samples/s)")
            if args.loop > 0:
                for _ in range(2):  # warm-up, as trainer_speed --loop
                    step(*data_batch(f, rng))
                t0 = time.perf_counter()
                for _ in range(args.loop):
                    step(*data_batch(f, rng))
                ms = (time.perf_counter() - t0) / args.loop * 1e3
                print(f"python loop ms/step (h5py batch + step, mean of {args.loop}): {ms:.1f}")


if __name__ == "__main__":
    main()
