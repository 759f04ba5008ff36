#!/usr/bin/env python3
# Time to equal error, dofarm against Cycles: reads the PFM images and the
# timing lines that bench/render_spp and bench/cycles/render_cornell.py print,
# and prints one table row per error level. Plain Python (no numpy), so it
# runs wherever the driver does.
#
#   compare.py DIR SPP_LIST REF_SPP
#   compare.py --bias DIR SPP_LIST REF_SPP
#
# DIR holds cycles_<N>.pfm, cycles_ref<REF>.pfm, dofarm_<N>.pfm,
# dofarm_ref<REF>.pfm, cycles_times.txt and dofarm_times.txt.
#
# Error of an image x against its own renderer's reference r (same renderer,
# same settings, independent random numbers, REF spp), two measures:
#   relative RMSE = sqrt(mean over pixels and channels of (x - r)^2) / mean(r)
#     (dominated by the bright parts of the image and by fireflies);
#   per-pixel relative RMSE = sqrt(mean of (x - r)^2 / (r^2 + 0.01))
#     (each pixel relative to its own value: dark, indirectly lit parts count
#     as much as bright ones).
# The reference's own noise adds to the measured MSE: with per-sample
# variance the same in both, E[(x - r)^2] = Var(x) (1 + N / REF), so the
# printed error is the measured one divided by sqrt(1 + N / REF).
#
# Also printed: the share of the squared error carried by the largest 0.1%
# of the squared differences, per image (how much a few pixels decide the
# relative RMSE).
#
# Time to an error level e: log(time) interpolated linearly in log(error)
# between the renderer's measured points; beyond its range, extrapolated from
# the nearest point with error ~ time^(-1/2) (Monte Carlo). The error levels
# are Cycles' errors at each sample count; the ratio is dofarm's time over
# Cycles' time at that error, for CPU time (the target) and wall time.
# --bias (for matched materials, where both render the same model): the two
# references against each other, the whole image and a 4x4 grid of regions,
# on the mean of R, G and B. The standard error of a region's mean comes from
# each renderer's own noise: the squared difference between its image at the
# largest N and its reference, (v_N - v_ref)^2, estimates Var(v_ref) (1 +
# REF / N) per pixel (pixels are independent), and z = (dofarm - Cycles) /
# sqrt(se_dofarm^2 + se_cycles^2). Fireflies make the noise heavy-tailed, so
# a |z| of 3-4 in one region of sixteen is not yet evidence of a bias.
import math
import os
import struct
import sys


def read_pfm(path):
    with open(path, "rb") as f:
        data = f.read()
    header, dims, scale, body = data.split(b"\n", 3)
    if header != b"PF":
        raise SystemExit("%s: not an RGB PFM" % path)
    w, h = map(int, dims.split())
    if float(scale) >= 0:
        raise SystemExit("%s: big-endian PFM not supported" % path)
    n = w * h * 3
    return (w, h), struct.unpack("<%df" % n, body[: 4 * n])


def relative_rmse(image, ref):
    (size_a, a), (size_b, b) = image, ref
    if size_a != size_b:
        raise SystemExit("image sizes differ: %s vs %s" % (size_a, size_b))
    mse = sum((x - y) * (x - y) for x, y in zip(a, b)) / len(a)
    return math.sqrt(mse) / (sum(b) / len(b))


def per_pixel_relative_rmse(image, ref):
    (_, a), (_, b) = image, ref
    return math.sqrt(sum((x - y) * (x - y) / (y * y + 0.01) for x, y in zip(a, b)) / len(a))


METRICS = (("relative RMSE", relative_rmse), ("per-pixel relative RMSE", per_pixel_relative_rmse))


def read_times(path):
    times = {}
    with open(path) as f:
        for line in f:
            p = line.split()
            if len(p) >= 6 and p[0] == "spp":
                n, cpu, wall = int(p[1]), float(p[3]), float(p[5])
                # Repeated runs: the fastest of each (a shared machine's load
                # only ever adds time).
                old = times.get(n, (math.inf, math.inf))
                times[n] = (min(old[0], cpu), min(old[1], wall))
    return times


def time_at_error(points, e):
    """points: [(error, time)] sorted by time; log-log interpolation."""
    pts = sorted(points, key=lambda p: p[1])
    le = math.log(e)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:]):
        if min(e0, e1) <= e <= max(e0, e1) and e0 != e1:
            w = (le - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + w * (math.log(t1) - math.log(t0)))
    # Outside the measured range: error ~ time^(-1/2) from the nearest end.
    e_near, t_near = min(pts, key=lambda p: abs(math.log(p[0]) - le))
    return t_near * (e_near / e) ** 2


def grey(image):
    (w, h), px = image
    return (w, h), [(px[3 * i] + px[3 * i + 1] + px[3 * i + 2]) / 3.0 for i in range(w * h)]


def region_stats(ref, noisy, n, ref_spp, x0, y0, x1, y1):
    """Mean of ref over the rectangle and its standard error (see the top)."""
    (w, _), r = ref
    _, v = noisy
    total = sq = 0.0
    count = 0
    for y in range(y0, y1):
        for x in range(x0, x1):
            i = y * w + x
            total += r[i]
            sq += (v[i] - r[i]) ** 2 / (1.0 + ref_spp / n)
            count += 1
    return total / count, math.sqrt(sq) / count


def bias(folder, spps, ref_spp):
    n = max(spps)
    img = {}
    for name in ("cycles", "dofarm"):
        img[name] = (grey(read_pfm(os.path.join(folder, "%s_ref%d.pfm" % (name, ref_spp)))),
                     grey(read_pfm(os.path.join(folder, "%s_%d.pfm" % (name, n)))))
    (w, h), _ = img["cycles"][0]
    if img["dofarm"][0][0] != (w, h):
        raise SystemExit("image sizes differ")

    def compare(x0, y0, x1, y1):
        md, sd = region_stats(*img["dofarm"], n, ref_spp, x0, y0, x1, y1)
        mc, sc = region_stats(*img["cycles"], n, ref_spp, x0, y0, x1, y1)
        z = (md - mc) / math.hypot(sd, sc) if sd > 0 or sc > 0 else 0.0
        return md, mc, md / mc - 1.0 if mc > 0 else math.nan, math.hypot(sd, sc) / mc, z

    print("### bias: dofarm's %d-spp reference against Cycles' (mean of R, G, B)\n" % ref_spp)
    md, mc, rel, se, z = compare(0, 0, w, h)
    print("whole image: dofarm %.5f, Cycles %.5f, difference %+.3f%% (standard error %.3f%%, "
          "z %+.2f)\n" % (md, mc, 100 * rel, 100 * se, z))
    print("| region (row from the top, column) | dofarm | Cycles | difference | std. error | z |")
    print("| --- | --- | --- | --- | --- | --- |")
    grid, worst = 4, 0.0
    for gy in range(grid):
        for gx in range(grid):
            # PFM rows run bottom-up: region row 0 is the top of the image.
            y1 = h - gy * h // grid
            y0 = h - (gy + 1) * h // grid
            x0, x1 = gx * w // grid, (gx + 1) * w // grid
            md, mc, rel, se, z = compare(x0, y0, x1, y1)
            worst = max(worst, abs(z))
            print("| %d, %d | %.5f | %.5f | %+.2f%% | %.2f%% | %+.2f |" % (gy, gx, md, mc, 100 * rel,
                                                                      100 * se, z))
    print("\nlargest |z| over the %d regions: %.2f" % (grid * grid, worst))


def main():
    if len(sys.argv) == 5 and sys.argv[1] == "--bias":
        bias(sys.argv[2], [int(s) for s in sys.argv[3].split(",")], int(sys.argv[4]))
        return
    if len(sys.argv) != 4:
        raise SystemExit("usage: compare.py [--bias] DIR SPP_LIST REF_SPP")
    folder, spps, ref_spp = sys.argv[1], [int(s) for s in sys.argv[2].split(",")], int(sys.argv[3])
    for metric, error in METRICS:
        print("### %s\n" % metric)
        report(folder, spps, ref_spp, metric, error)
        print()
    tail(folder, spps, ref_spp)


def tail(folder, spps, ref_spp, fraction=0.001):
    """How concentrated the squared error is: the share carried by the
    largest 0.1% of the per-value squared differences (a few hundred values
    of a 256x256 RGB image). A share near 1 means a handful of pixels
    (fireflies, a badly sampled edge) decide the relative RMSE."""
    print("### share of the squared error in the largest %.1f%% of values\n" % (100 * fraction))
    print("| renderer | " + " | ".join("%d spp" % n for n in spps) + " |")
    print("| --- | " + " | ".join("---" for _ in spps) + " |")
    for name in ("cycles", "dofarm"):
        (_, r) = read_pfm(os.path.join(folder, "%s_ref%d.pfm" % (name, ref_spp)))
        shares = []
        for n in spps:
            (_, a) = read_pfm(os.path.join(folder, "%s_%d.pfm" % (name, n)))
            se = sorted(((x - y) * (x - y) for x, y in zip(a, r)), reverse=True)
            k = max(1, int(len(se) * fraction))
            total = sum(se)
            shares.append(sum(se[:k]) / total if total > 0 else 0.0)
        print("| %s | " % name + " | ".join("%.2f" % v for v in shares) + " |")
    print()


def report(folder, spps, ref_spp, metric, error):
    rows = {}
    for name in ("cycles", "dofarm"):
        ref = read_pfm(os.path.join(folder, "%s_ref%d.pfm" % (name, ref_spp)))
        times = read_times(os.path.join(folder, "%s_times.txt" % name))
        rows[name] = []
        for n in spps:
            e = error(read_pfm(os.path.join(folder, "%s_%d.pfm" % (name, n))), ref)
            e /= math.sqrt(1.0 + n / ref_spp)
            cpu, wall = times[n]
            rows[name].append((n, e, cpu, wall))

    print("| renderer | spp | %s | CPU s | wall s | error x sqrt(CPU s) |" % metric)
    print("| --- | --- | --- | --- | --- | --- |")
    for name in ("cycles", "dofarm"):
        for n, e, cpu, wall in rows[name]:
            print("| %s | %d | %.4f | %.2f | %.2f | %.4f |" % (name, n, e, cpu, wall,
                                                           e * math.sqrt(cpu)))
    print()
    print("| error level (Cycles at spp) | %s | Cycles CPU s | dofarm CPU s "
          "| **ratio CPU** | ratio wall |" % metric)
    print("| --- | --- | --- | --- | --- | --- |")
    d_cpu = [(e, cpu) for _, e, cpu, _ in rows["dofarm"]]
    d_wall = [(e, wall) for _, e, _, wall in rows["dofarm"]]
    for n, e, cpu, wall in rows["cycles"]:
        t_cpu = time_at_error(d_cpu, e)
        t_wall = time_at_error(d_wall, e)
        print("| %d | %.4f | %.2f | %.2f | **%.2f** | %.2f |" % (n, e, cpu, t_cpu, t_cpu / cpu,
                                                                 t_wall / wall))

main()
