#!/usr/bin/env python3
"""Paired per-frame whole-frame SSIM of two crop_vs_frame outputs A and B
(build/bench/trainer/crop_vs_frame ... > FILE), A - B frame by frame:
mean, standard error and how many frames A wins. Asserts nothing."""
import math
import sys


def frames(path):
    out = {}
    for line in open(path):
        p = line.split()
        if len(p) == 5 and p[0].startswith("shard-"):
            out[(p[0], p[1])] = float(p[3])
    return out


a, b = frames(sys.argv[1]), frames(sys.argv[2])
d = [a[k] - b[k] for k in sorted(a) if k in b]
m = sum(d) / len(d)
se = math.sqrt(sum((x - m) ** 2 for x in d) / (len(d) - 1) / len(d))
print(f"{sys.argv[1]} - {sys.argv[2]}: {m:+.4f} +- {se:.4f} (SE, {len(d)} frames), "
      f"A higher on {sum(x > 0 for x in d)}")
