#!/usr/bin/env python3
"""The tables and the plot of bench/trainer/dof_study.sh.

  study_tables.py study OUT SIDE NAME=DESCRIPTION...
      one study's OUT/results.md, results.csv and results.svg from its
      reports (OUT/reports/NAME, and NAME-coc0 where the CoC probe ran) and
      runs (OUT/runs/NAME/loss.csv);
  study_tables.py held-out-check DOFARM HELD_DIR TRAIN_DIR...
      exits 1 (saying which) when a shard of HELD_DIR holds a frame that a
      shard of a TRAIN_DIR of the same scene and seed holds too (read with
      `DOFARM inspect --json`), or when HELD_DIR has no shard;
  study_tables.py seeds OUT SIDE "S1 S2 ..." NAME=DESCRIPTION...
      the tables across the seeds' studies OUT/seed-S: per configuration the
      mean and the range over the seeds, SSIM by CoC band, the CoC input's
      gain and the CoC probe seed by seed;
  study_tables.py paired A/report.json B/report.json
      SSIM of A − SSIM of B by region on the frames both scored, with a 95%
      interval from a paired bootstrap over 32-pixel tiles (paired_ssim()).

SIDE is the frame side the denoise was timed at. Every file is written
whole and then renamed over the old one. Prints the tables; asserts nothing.
"""
import csv
import json
import math
import os
import shutil
import sys

# The CoC bands of the report (trainer/eval.h, kFocusRegions): in focus,
# then the out-of-focus bands.
BANDS = (("in_focus", "< 1 px"), ("coc_1_4", "1–4 px"), ("coc_4_16", "4–16 px"),
         ("coc_16_up", "≥ 16 px"))


def num(v):
    """A report's or a CSV's number; NaN for null or empty."""
    return float("nan") if v is None or v == "" else float(v)


def fmt(v, spec):
    return "–" if isinstance(v, float) and not math.isfinite(v) else format(v, spec)


def write_replacing(path, text):
    with open(path + ".tmp", "w") as f:
        f.write(text)
    os.replace(path + ".tmp", path)


def shard_infos(dofarm, folder):
    """(file, attributes) of every shard of a farm output folder."""
    import subprocess
    out = []
    for name in sorted(os.listdir(folder)):
        if not name.endswith(".h5"):
            continue
        path = os.path.join(folder, name)
        j = json.loads(subprocess.run([dofarm, "inspect", "--json", path], check=True,
                                      capture_output=True, text=True).stdout)
        out.append((path, j["attributes"]))
    return out


def coc_pairs(configs, present):
    """(CoC network, no-CoC twin) for every twin in present: `_nococ` (for
    the project default, at the thesis's no-DOF widths) and `_nococ_wide`
    (at the CoC network's own widths)."""
    return [(c, c + t) for c in configs for t in ("_nococ", "_nococ_wide")
            if c in present and c + t in present]


def paired_ssim(rep_a, rep_b, region, resamples=1000, seed=1):
    """(A − B, low, high, tiles): the difference of two reports' mean denoised
    SSIM over `region` on the frames both scored (matched by shard and frame),
    and its 95% percentile interval from a paired bootstrap. Each report
    frame keeps its SSIM map summed per 32-pixel tile (frames[].denoised_tiles,
    trainer/eval.cpp); a resample draws each frame's tiles with replacement,
    the same tiles for A and B, and averages the frames' differences as the
    reports' summaries average frames. It measures how much the difference
    depends on which parts of these frames were scored, not the spread over
    training seeds (the seeds table). Nones where no frame has tiles."""
    import random

    def tiles(rep):
        out = {}
        for f in rep.get("frames", []):
            t = (f.get("denoised_tiles") or {}).get("regions", {}).get(region)
            if t:
                out[(f["shard"], f["frame"])] = t
        return out
    ta, tb = tiles(rep_a), tiles(rep_b)
    frames = []  # per frame: [(sum A, sum B, count)] over tiles with windows in the region
    for key in sorted(set(ta) & set(tb)):
        a, b = ta[key], tb[key]
        if a["count"] != b["count"]:
            raise ValueError(f"frame {key}: the two reports' {region} tiles differ (other data?)")
        frames.append([(x, y, n) for x, y, n in zip(a["ssim_sum"], b["ssim_sum"], a["count"]) if n])
    frames = [f for f in frames if f]
    if not frames:
        return None, None, None, 0

    def diff(draw):
        total = 0.0
        for units in draw:
            sa = sb = n = 0.0
            for x, y, c in units:
                sa += x
                sb += y
                n += c
            total += (sa - sb) / n
        return total / len(draw)
    rng = random.Random(seed)
    boot = sorted(diff([rng.choices(u, k=len(u)) for u in frames]) for _ in range(resamples))
    return (diff(frames), boot[int(0.025 * resamples)], boot[int(0.975 * resamples) - 1],
            sum(len(u) for u in frames))


def paired_rows(rep_a, rep_b, regions):
    """One markdown cell per region: "A − B [low, high]", "–" for a region
    without pixels; None when the reports have no tiles."""
    cells = []
    for r in regions:
        d, lo, hi, n = paired_ssim(rep_a, rep_b, r)
        cells.append(f"{d:+.4f} [{lo:+.4f}, {hi:+.4f}]" if n else "–")
    return cells if any(c != "–" for c in cells) else None


def held_out_check(dofarm, held, train_dirs):
    """0 when no shard of `held` shares a frame with a training shard of the
    same scene (content hash) and seed; 1, naming both, otherwise."""
    held_shards = shard_infos(dofarm, held)
    if not held_shards:
        print(f"{held}: no shards", file=sys.stderr)
        return 1
    bad = 0
    for d in train_dirs:
        for tpath, t in shard_infos(dofarm, d):
            for hpath, h in held_shards:
                same = (t["scene_hash"], t["seed"]) == (h["scene_hash"], h["seed"])
                lo = max(t["frame_start"], h["frame_start"])
                hi = min(t["frame_end"], h["frame_end"])
                if same and lo <= hi:
                    print(f"{hpath}: frames {lo}..{hi} are in the training shard {tpath} "
                          "(same scene and seed)", file=sys.stderr)
                    bad = 1
    return bad


def held_out_table(out, label):
    """The table over the held-out frames (OUT/reports-held-out/NAME), or []."""
    rows = []
    for c in label:
        path = os.path.join(out, "reports-held-out", c, "report.json")
        if os.path.exists(path):
            rows.append((c, json.load(open(path))))
    if not rows:
        return []
    ceil = rows[0][1].get("reference_ceiling") or {}
    frames = sorted({f["frame"] for f in rows[0][1].get("frames", []) if "frame" in f})
    md = ["", "**Held-out frames at clean references** (`--held-out`: frames "
          + ", ".join(map(str, frames)) + ", which no configuration trained on; the same weights). "
          f"Reference ceiling of these frames (SSIM of each reference's two halves, a lower bound): {fmt(num(ceil.get('mean_ssim')), '.4f')} "
          f"(an exact denoiser against these references: {fmt(num(ceil.get('exact_denoiser_mean_ssim')), '.4f')}).", "",
          "| configuration | SSIM all | SSIM in focus | SSIM out of focus | PSNR all (dB) | PSNR in | "
          "PSNR out | relMSE all | relMSE in | relMSE out | " +
          " | ".join(f"SSIM {name}" for _, name in BANDS[1:]) + " |",
          "| --- " * (11 + len(BANDS) - 1) + "|"]
    by = {}
    for c, rep in rows:
        d = rep["summary"]["denoised"]
        by[c] = d
        md.append("| " + " | ".join(
            [f"`{c}` {label[c]}"] +
            [fmt(num(d[r]["ssim"]), ".4f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(num(d[r]["psnr"]), ".2f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(num(d[r]["rel_mse"]), ".4f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(num(d.get(r, {}).get("ssim")), ".4f") for r, _ in BANDS[1:]]) + " |")
    for c, t in coc_pairs(label, by):
        a, b = by[c], by[t]
        diff = lambda r, k: num(a.get(r, {}).get(k)) - num(b.get(r, {}).get(k))
        md.append("| " + " | ".join(
            [f"CoC input: `{c}` − `{t}`"] +
            [fmt(diff(r, "ssim"), "+.4f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(diff(r, "psnr"), "+.2f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(diff(r, "rel_mse"), "+.4f") for r in ("all", "in_focus", "out_of_focus")] +
            [fmt(diff(r, "ssim"), "+.4f") for r, _ in BANDS[1:]]) + " |")
    return md


def one_study(out, side, label):
    """One study's table, CSV and plot."""
    configs = list(label)
    cols = ["config", "description", "frames",
            "ssim_all", "ssim_in", "ssim_out", "psnr_all", "psnr_in", "psnr_out",
            "relmse_all", "relmse_in", "relmse_out", "flicker_all", "flicker_in", "flicker_out",
            "ssim_coc_1_4", "ssim_coc_4_16", "ssim_coc_16_up",
            f"ms_per_{side}px_frame", "steps", "train_seconds", "denoise_threads"]
    bands = BANDS
    rows = []
    for c in configs:
        rep = json.load(open(os.path.join(out, "reports", c, "report.json")))
        d = rep["summary"]["denoised"]
        steps, seconds = 0, 0.0
        with open(os.path.join(out, "runs", c, "loss.csv")) as f:
            for r in csv.DictReader(f):
                steps = int(r["step"])
                seconds += float(r["seconds"])
        row = {"config": c, "description": label[c], "frames": rep["summary"]["frames"]}
        for m, key in (("ssim", "ssim"), ("psnr", "psnr"), ("relmse", "rel_mse"), ("flicker", "flicker")):
            for region, short in (("all", "all"), ("in_focus", "in"), ("out_of_focus", "out")):
                v = d[region][key]
                row[f"{m}_{short}"] = num(v)
        for region, _ in bands[1:]:
            row[f"ssim_{region}"] = num(d.get(region, {}).get("ssim"))
        row["share"] = rep["summary"].get("pixel_share", {})
        t = rep.get("denoise_ms_at_size") or {}
        row[f"ms_per_{side}px_frame"] = float(t.get("ms", float("nan")))
        # intra-op threads the denoise was timed on (reports before 2026-12-03: unknown)
        row["denoise_threads"] = float(t.get("threads", float("nan")))
        row["steps"] = steps
        row["train_seconds"] = seconds
        rows.append(row)

    with open(os.path.join(out, "results.csv.tmp"), "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for r in rows:
            w.writerow([r[c] if not isinstance(r[c], float) else repr(r[c]) for c in cols])
    os.replace(os.path.join(out, "results.csv.tmp"), os.path.join(out, "results.csv"))

    md = ["| configuration | SSIM all | SSIM in focus | SSIM out of focus | PSNR all (dB) | PSNR in | "
          "PSNR out | relMSE all | relMSE in | relMSE out | flicker all | flicker in | flicker out | "
          f"ms / {side}² frame | steps | train wall s |",
          "| --- " * 16 + "|"]
    threads = {fmt(r["denoise_threads"], ".0f") for r in rows}
    def ms_cell(r):
        ms = fmt(r[f"ms_per_{side}px_frame"], ".0f")
        # rows timed on different thread counts say so in the cell
        return ms if len(threads) == 1 else f"{ms} ({fmt(r['denoise_threads'], '.0f')} thr)"
    for r in rows:
        md.append("| " + " | ".join([
            f"`{r['config']}` {r['description']}",
            *(fmt(r[f"ssim_{s}"], ".4f") for s in ("all", "in", "out")),
            *(fmt(r[f"psnr_{s}"], ".2f") for s in ("all", "in", "out")),
            *(fmt(r[f"relmse_{s}"], ".4f") for s in ("all", "in", "out")),
            *(fmt(r[f"flicker_{s}"], ".3g") for s in ("all", "in", "out")),
            ms_cell(r), str(r["steps"]), fmt(r["train_seconds"], ".0f"),
        ]) + " |")
    frames = sorted({r["frames"] for r in rows})
    first_report = json.load(open(os.path.join(out, "reports", configs[0], "report.json")))
    held = bool(first_report.get("held_out"))
    ceil = first_report.get("reference_ceiling") or {}
    kind = ("Held-out frames (`eval --held-out`: frames no configuration trained on, "
            "rendered apart)" if held else "Validation frames")
    note = (f"\n{kind}: {', '.join(map(str, frames))}; weights after the last step. "
            "Reference ceiling of these frames (SSIM of each reference's two halves, a lower "
            f"bound): {fmt(num(ceil.get('mean_ssim')), '.4f')}; an exact denoiser against these "
            f"references: {fmt(num(ceil.get('exact_denoiser_mean_ssim')), '.4f')}. "
            "SSIM and PSNR on sRGB clamped to [0, 1]; relative MSE and flicker on linear HDR "
            "(docs/trainer.md, \"Evaluation\"). In focus: CoC < 1 px." +
            ("" if threads == {"–"} else
             f" Denoise timed on {next(iter(threads))} intra-op thread(s)." if len(threads) == 1
             else " Denoise timed on the intra-op threads each cell names.") + "\n")
    # SSIM by circle of confusion, and what the CoC input adds in each band where
    # a configuration and its copy without the CoC input were both run.
    by = {r["config"]: r for r in rows}
    share = next((r["share"] for r in rows if r["share"]), {})
    def band_ssim(r, region):
        return r["ssim_in"] if region == "in_focus" else r[f"ssim_{region}"]
    coc_md = ["", "SSIM by circle of confusion (validation pixels in each band: " +
              ", ".join(f"{name} {100 * share.get(region, 0):.1f}%" for region, name in bands) + "):", "",
              "| configuration | " + " | ".join(name for _, name in bands) + " |",
              "| --- " * (len(bands) + 1) + "|"]
    for r in rows:
        coc_md.append(f"| `{r['config']}` | " +
                      " | ".join(fmt(band_ssim(r, region), ".4f") for region, _ in bands) + " |")
    pairs = coc_pairs(configs, by)
    for c, t in pairs:
        a, b = by[c], by[t]
        coc_md.append(f"| CoC input: `{c}` − `{t}` | " +
                      " | ".join(fmt(band_ssim(a, region) - band_ssim(b, region), "+.4f")
                                 for region, _ in bands) + " |")
    # The CoC probe: SSIM when fed CoC 0 everywhere, minus SSIM with the frame's own.
    probe_rows = []
    for r in rows:
        path = os.path.join(out, "reports", r["config"] + "-coc0", "report.json")
        if not os.path.exists(path):
            continue
        pd = json.load(open(path))["summary"]["denoised"]
        def probe_ssim(region):
            return num(pd.get(region, {}).get("ssim"))
        probe_rows.append(f"| `{r['config']}` fed CoC 0 | " +
                          " | ".join(fmt(probe_ssim(region) - band_ssim(r, region), "+.4f")
                                     for region, _ in bands) + " |")
    paired_md = []
    regions = [("all", "all"), ("out_of_focus", "out of focus")] + list(bands)
    for c, t in pairs:
        ra = json.load(open(os.path.join(out, "reports", c, "report.json")))
        rb = json.load(open(os.path.join(out, "reports", t, "report.json")))
        cells = paired_rows(ra, rb, [r for r, _ in regions])
        if cells:
            paired_md.append(f"| `{c}` − `{t}` | " + " | ".join(cells) + " |")
    def table(intro, first, columns, body):
        return ["", intro, "", f"| {first} | " + " | ".join(name for _, name in columns) + " |",
                "| --- " * (len(columns) + 1) + "|"] + body
    if paired_md:
        coc_md += table("The CoC input's gain with a 95% interval (`study_tables.py paired`: a "
                        "paired bootstrap over 32-pixel tiles of these frames; it says how much the "
                        "gain depends on which parts of the frames were scored, not how it varies "
                        "over training seeds):", "pair", regions, paired_md)
    if probe_rows:
        coc_md += table("The CoC probe (`eval --coc-override 0`): SSIM when the network is fed a "
                        "CoC of 0 px everywhere (\"all sharp\"), minus SSIM with the frame's own "
                        "CoC, by the frame's own CoC band (a model that ignores its CoC input scores "
                        "+0 everywhere):", "configuration", bands, probe_rows)
    # Side-by-side crops: the windows eval chose from the data's CoC (the same
    # for every configuration), copied to OUT/crops/ so that results.md and its
    # pictures can be published together.
    crops_md = []
    first = json.load(open(os.path.join(out, "reports", configs[0], "report.json"))).get("crops", [])
    if first:
        os.makedirs(os.path.join(out, "crops"), exist_ok=True)
        def copy(c, rel, name):
            shutil.copyfile(os.path.join(out, "reports", c, rel), os.path.join(out, "crops", name))
            return "crops/" + name
        crops_md = ["", "Crops (2×) of the sharpest and the most blurred window of validation frames, "
                    "chosen from the circle of confusion; the same windows for every configuration:", "",
                    "| window | noisy | " + " | ".join(f"`{c}`" for c in configs) + " | reference |",
                    "| --- " * (len(configs) + 3) + "|"]
        for k, w in enumerate(first):
            stem = f"crop-{w['index']}-{w['region']}"
            cells = [f"{w['scene']} frame {w['frame']}, {w['region'].replace('_', ' ')}, "
                     f"mean CoC {w['mean_coc_px']:.1f} px",
                     f"![]({copy(configs[0], w['noisy'], stem + '-noisy.png')})"]
            for c in configs:
                other = json.load(open(os.path.join(out, "reports", c, "report.json"))).get("crops", [])
                same = [o for o in other if (o["shard"], o["frame"], o["region"], o["x"], o["y"]) ==
                        (w["shard"], w["frame"], w["region"], w["x"], w["y"])]
                cells.append(f"![]({copy(c, same[0]['denoised'], f'{stem}-{c}.png')})" if same else "–")
            cells.append(f"![]({copy(configs[0], w['reference'], stem + '-reference.png')})")
            crops_md.append("| " + " | ".join(cells) + " |")
    held_md = held_out_table(out, label)
    write_replacing(os.path.join(out, "results.md"),
                    "\n".join(md) + "\n" + note + "\n".join(coc_md) + "\n" + "\n".join(held_md) +
                    "\n" + "\n".join(crops_md) + "\n")

    # Plot: 1 - SSIM (all pixels) against ms per frame, one labelled point each.
    W, H, L, R, T, B = 720, 440, 80, 250, 40, 60
    pts = [(r[f"ms_per_{side}px_frame"], 1 - r["ssim_all"], r["config"]) for r in rows
           if math.isfinite(r[f"ms_per_{side}px_frame"]) and math.isfinite(r["ssim_all"])]
    def span(vals):
        lo, hi = min(vals), max(vals)
        pad = (hi - lo) * 0.1 or abs(hi) * 0.1 or 1.0
        return lo - pad, hi + pad
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>',
           f'<text x="{(L + W - R) / 2}" y="22" text-anchor="middle" font-size="15">'
           f'Error against denoise time ({len(pts)} configurations)</text>']
    if pts:
        x0, x1 = span([p[0] for p in pts])
        y0, y1 = span([p[1] for p in pts])
        y0 = max(0.0, y0)
        X = lambda v: L + (v - x0) / (x1 - x0) * (W - L - R)
        Y = lambda v: H - B - (v - y0) / (y1 - y0) * (H - T - B)
        svg.append(f'<rect x="{L}" y="{T}" width="{W - L - R}" height="{H - T - B}" fill="none" stroke="#444"/>')
        for i in range(5):
            xv, yv = x0 + (x1 - x0) * i / 4, y0 + (y1 - y0) * i / 4
            svg.append(f'<text class="xtick" x="{X(xv):.1f}" y="{H - B + 16}" text-anchor="middle">{xv:.0f}</text>')
            svg.append(f'<text class="ytick" x="{L - 6}" y="{Y(yv) + 4:.1f}" text-anchor="end">{yv:.4f}</text>')
        svg.append(f'<text x="{(L + W - R) / 2}" y="{H - 18}" text-anchor="middle">'
                   f'denoise time per {side}×{side} frame (ms)</text>')
        svg.append(f'<text transform="translate(20 {(T + H - B) / 2}) rotate(-90)" text-anchor="middle">'
                   '1 − SSIM, all pixels (lower is better)</text>')
        colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b"]
        for i, (xv, yv, name) in enumerate(pts):
            col = colours[i % len(colours)]
            svg.append(f'<circle cx="{X(xv):.1f}" cy="{Y(yv):.1f}" r="5" fill="{col}"/>')
            svg.append(f'<circle cx="{W - R + 20}" cy="{T + 10 + 20 * i}" r="5" fill="{col}"/>')
            svg.append(f'<text x="{W - R + 30}" y="{T + 14 + 20 * i}">{label[name]}</text>')
    svg.append("</svg>")
    write_replacing(os.path.join(out, "results.svg"), "\n".join(svg) + "\n")
    print("\n".join(md) + "\n" + note + "\n".join(coc_md) + "\n" + "\n".join(held_md) + "\n")
    print(f"dof_study.sh: {out}/results.md, results.csv, results.svg")


def across_seeds(out, side, seeds, label):
    """The tables across the seeds' studies OUT/seed-S."""
    configs = list(label)
    bands = BANDS
    # Per seed: its results.csv rows and, per configuration, the summary of its
    # report and of its CoC probe.
    per = {}  # (config, seed) -> {"csv": row, "denoised": ..., "probe": ... or None}
    for s in seeds:
        d = os.path.join(out, f"seed-{s}")
        with open(os.path.join(d, "results.csv")) as f:
            rows = {r["config"]: r for r in csv.DictReader(f)}
        for c in configs:
            rep = json.load(open(os.path.join(d, "reports", c, "report.json")))["summary"]["denoised"]
            p = os.path.join(d, "reports", c + "-coc0", "report.json")
            probe = json.load(open(p))["summary"]["denoised"] if os.path.exists(p) else None
            per[(c, s)] = {"csv": rows[c], "denoised": rep, "probe": probe}
    def ssim(summary, region):
        return num((summary or {}).get(region, {}).get("ssim"))
    def finite(vals):
        return [v for v in vals if math.isfinite(v)]
    def mean_range(vals, spec):
        v = finite(vals)
        if not v:
            return "–"
        m = sum(v) / len(v)
        if len(v) == 1:
            return format(m, spec)
        return f"{format(m, spec)} ({format(min(v), spec)} … {format(max(v), spec)})"
    def mean(vals):
        v = finite(vals)
        return sum(v) / len(v) if v else float("nan")

    cols = [("ssim_all", "SSIM all", ".4f"), ("ssim_in", "SSIM in focus", ".4f"),
            ("ssim_out", "SSIM out of focus", ".4f"), ("psnr_all", "PSNR all (dB)", ".2f"),
            ("relmse_all", "relMSE all", ".4f"), ("flicker_all", "flicker all", ".3g"),
            (f"ms_per_{side}px_frame", f"ms / {side}² frame", ".0f")]
    md = [f"Across seeds {', '.join(seeds)}: the mean, and in brackets the lowest and the highest "
          "seed (each seed's own tables: seed-S/results.md).", "",
          "| configuration | " + " | ".join(name for _, name, _ in cols) + " |",
          "| --- " * (len(cols) + 1) + "|"]
    for c in configs:
        md.append(f"| `{c}` {label[c]} | " + " | ".join(
            mean_range([num(per[(c, s)]["csv"][k]) for s in seeds], spec) for k, _, spec in cols) + " |")
    md += ["", "SSIM by circle of confusion, mean (lowest … highest seed):", "",
           "| configuration | " + " | ".join(name for _, name in bands) + " |",
           "| --- " * (len(bands) + 1) + "|"]
    for c in configs:
        md.append(f"| `{c}` | " + " | ".join(
            mean_range([ssim(per[(c, s)]["denoised"], r) for s in seeds], ".4f") for r, _ in bands) + " |")
    pairs = coc_pairs(configs, label)
    if pairs:
        md += ["", "The CoC input's gain (SSIM with it − without it), by CoC band: the mean, then "
               "seed by seed (" + ", ".join(seeds) + "):", "",
               "| pair | " + " | ".join(name for _, name in bands) + " |",
               "| --- " * (len(bands) + 1) + "|"]
        for c, t in pairs:
            cells = []
            for r, _ in bands:
                g = [ssim(per[(c, s)]["denoised"], r) - ssim(per[(t, s)]["denoised"], r)
                     for s in seeds]
                cells.append(format(mean(g), "+.4f") + " (" + ", ".join(format(x, "+.4f") for x in g) + ")")
            md.append(f"| `{c}` − `{t}` | " + " | ".join(cells) + " |")
    probed = [c for c in configs if all(per[(c, s)]["probe"] for s in seeds)]
    if probed:
        md += ["", "The CoC probe (`eval --coc-override 0`, the network told that everything is "
               "sharp): SSIM change by the frame's own CoC band, the mean, then seed by seed:", "",
               "| configuration | " + " | ".join(name for _, name in bands) + " |",
               "| --- " * (len(bands) + 1) + "|"]
        for c in probed:
            cells = []
            for r, _ in bands:
                g = [ssim(per[(c, s)]["probe"], r) - ssim(per[(c, s)]["denoised"], r) for s in seeds]
                cells.append(format(mean(g), "+.4f") + " (" + ", ".join(format(x, "+.4f") for x in g) + ")")
            md.append(f"| `{c}` fed CoC 0 | " + " | ".join(cells) + " |")
    write_replacing(os.path.join(out, "results.md"), "\n".join(md) + "\n")
    # Every seed's rows in one CSV, the seed first.
    with open(os.path.join(out, "results.csv.tmp"), "w", newline="") as f:
        w = None
        for s in seeds:
            for c in configs:
                row = per[(c, s)]["csv"]
                if w is None:
                    w = csv.writer(f, lineterminator="\n")
                    w.writerow(["seed"] + list(row))
                w.writerow([s] + list(row.values()))
    os.replace(os.path.join(out, "results.csv.tmp"), os.path.join(out, "results.csv"))
    print("\n".join(md))
    print(f"dof_study.sh: {out}/results.md, results.csv (across seeds)")


def main(argv):
    usage = ("usage: study_tables.py study OUT SIDE NAME=DESCRIPTION... | "
             "held-out-check DOFARM HELD_DIR TRAIN_DIR... | "
             "seeds OUT SIDE \"S1 S2 ...\" NAME=DESCRIPTION... | "
             "paired A/report.json B/report.json")
    if len(argv) >= 4 and argv[1] == "study":
        one_study(argv[2], int(argv[3]), dict(arg.split("=", 1) for arg in argv[4:]))
    elif len(argv) >= 5 and argv[1] == "held-out-check":
        return held_out_check(argv[2], argv[3], argv[4:])
    elif len(argv) == 4 and argv[1] == "paired":
        a, b = json.load(open(argv[2])), json.load(open(argv[3]))
        print(f"A = {argv[2]}\nB = {argv[3]}\n")
        print("| region | A − B | 95% interval | tiles |\n| --- | --- | --- | --- |")
        for r in ["all", "out_of_focus"] + [b_ for b_, _ in BANDS]:
            d, lo, hi, n = paired_ssim(a, b, r)
            print(f"| {r} | " + (f"{d:+.4f} | [{lo:+.4f}, {hi:+.4f}] | {n}" if n else "– | – | 0") + " |")
    elif len(argv) >= 5 and argv[1] == "seeds":
        across_seeds(argv[2], int(argv[3]), argv[4].split(),
                     dict(arg.split("=", 1) for arg in argv[5:]))
    else:
        print(usage, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
