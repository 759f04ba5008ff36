#!/usr/bin/env bash
# The depth-of-field study of issue 13 in one command: on the same shards and
# the same number of optimiser steps, train and evaluate
#   thesis            (a) the thesis-exact preset, with its CoC input
#   thesis_nococ      (b) the same without the CoC input (11 channels, widths 32..101:
#                         the thesis's no-DOF network)
#   default           (c) the project's default configuration
#   thesis_focus      (d) (a) + focus-weighted loss (thesis 6.3)
#   thesis_prefilter  (d) (a) + CoC-sized albedo prefilter (thesis 6.1)
#   thesis_recurrent  (d) (a) + recurrent encoder blocks and the temporal loss
#                         (Chaitanya 2017; thesis 6.3)
# and, asked for by name (--configs "thesis abl_radiance ..." or --configs
# ablation), the one-at-a-time ablation of the thesis preset against the
# project's default: (a) with one key set to the project's value
#   abl_radiance      radiance:log1p input and training space
#   abl_normal        normal:as_stored ([-1, 1])
#   abl_depth         depth:focal, z / (z + focal distance)
#   abl_coc           coc:log, log1p(c) / ln 33
#   abl_bottleneck    2 bottleneck convolutions
#   abl_decoder       the project's decoder (activations, 3x3 output convolution)
#   abl_gradloss      mean |dLoG| with a unit-L1 kernel instead of eq. 4.4
#   abl_schedule      1e-3 after a linear warm-up, x 0.97 per epoch, instead of eq. 4.5
# and the CoC ablation of the project's default (the thesis presets' eq. 4.5
# schedule starves on a small data set, so (a) against (b) can be mute):
#   default_nococ     (c) without the CoC input (--configs coc: default default_nococ)
# and write one table (OUT/results.md, OUT/results.csv) with, per
# configuration, SSIM / PSNR / relative MSE over all, in-focus and
# out-of-focus pixels, flicker, ms per 512² frame, training steps and wall
# time, and one plot of error against time (OUT/results.svg). Scores are on
# the validation frames of the run's split (the same frames for every
# configuration: the split is drawn from the shards' content).
#
#   bench/trainer/dof_study.sh [--steps N] [--out DIR] [--epochs E] [--time-size S] [--crops K]
#                              [--configs "thesis default ..."] [--seeds "1 2 3"]
#                              [--set KEY=VALUE]... [DATA_DIR...]
#
# --seeds: run the whole study once per training seed, each a study of its
# own in OUT/seed-S (with --set train.seed=S; its own table), and write the
# tables across seeds in OUT/results.md and OUT/results.csv: per
# configuration the mean and the range over the seeds, SSIM by CoC band, the
# CoC input's gain per band seed by seed, and the CoC probe. One seed
# cannot tell a difference from where a run happens to stop.
#
# DATA_DIR: farm output folders (default: out/study/cornell out/study/courtyard,
# rendered by bench/trainer/render_study.sh). Several folders are joined in
# OUT/data by symbolic links. --steps (default 4000) optimiser steps per
# configuration, as --epochs (default 10) epochs of ceil(steps / epochs)
# steps. --time-size (default 512) the frame side the denoise is timed at.
# --crops (default 2): side-by-side crops of the sharpest and the most
# blurred window of the K most blurred validation frames (`eval --crops`), the same windows
# for every configuration, gathered in OUT/crops/ and shown in results.md.
# --set is passed to every configuration's `train` (e.g. smaller models for
# a smoke run). Environment: DOFARM_TRAIN (default build/dofarm-train).
#
# Resumable: each configuration is its own run folder OUT/runs/NAME (a
# dofarm-train run, which resumes where it stopped) and its report
# OUT/reports/NAME; a finished configuration (OUT/runs/NAME/study.done
# naming the same step count) is not trained again, a report newer than the
# run's checkpoint is not made again. Kill it at any point (Ctrl-C: the run
# writes its checkpoint) and run the same command again.
#
# Prints figures; never asserts. Exit status: 0, 2 on bad arguments.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
TRAIN=${DOFARM_TRAIN:-$ROOT/build/dofarm-train}
STEPS=4000
EPOCHS=10
OUT=$ROOT/out/study/results
TIME_SIZE=512
CROPS=2
CONFIGS="thesis thesis_nococ default thesis_focus thesis_prefilter thesis_recurrent"
SETS=()
DATA=()
SEEDS=""
PASS=()  # the arguments each seed's study gets (all but --seeds and --out)
usage() { sed -n '2,54p' "$0" | sed 's/^# \{0,1\}//'; }
die() { echo "dof_study.sh: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case $1 in
    --steps) STEPS=${2:?}; PASS+=("$1" "$2"); shift 2 ;;
    --epochs) EPOCHS=${2:?}; PASS+=("$1" "$2"); shift 2 ;;
    --out) OUT=${2:?}; shift 2 ;;
    --time-size) TIME_SIZE=${2:?}; PASS+=("$1" "$2"); shift 2 ;;
    --crops) CROPS=${2:?}; PASS+=("$1" "$2"); shift 2 ;;
    --configs) CONFIGS=${2:?}; PASS+=("$1" "$2"); shift 2 ;;
    --seeds) SEEDS=${2?}; shift 2 ;;
    --set) SETS+=(--set "${2:?}"); PASS+=("$1" "$2"); shift 2 ;;
    -h|--help) usage; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) DATA+=("$1"); PASS+=("$1"); shift ;;
  esac
done
[[ $STEPS =~ ^[1-9][0-9]*$ ]] || die "--steps: expected a positive integer, got '$STEPS'"
[[ $EPOCHS =~ ^[1-9][0-9]*$ ]] || die "--epochs: expected a positive integer, got '$EPOCHS'"
[[ $TIME_SIZE =~ ^[1-9][0-9]*$ ]] || die "--time-size: expected a positive integer, got '$TIME_SIZE'"
[[ $CROPS =~ ^[0-9]+$ ]] || die "--crops: expected a non-negative integer, got '$CROPS'"
[ -x "$TRAIN" ] || die "$TRAIN not found; build dofarm-train or set DOFARM_TRAIN"
command -v python3 > /dev/null || die "python3 is needed for the table and the plot"
[ ${#DATA[@]} -gt 0 ] || DATA=("$ROOT/out/study/cornell" "$ROOT/out/study/courtyard")
for d in "${DATA[@]}"; do
  [ -d "$d" ] || die "no data folder $d (render the study set with bench/trainer/render_study.sh)"
done
ABLATION="thesis abl_radiance abl_normal abl_depth abl_coc abl_bottleneck abl_decoder abl_gradloss abl_schedule default"
for s in $SEEDS; do
  [[ $s =~ ^[0-9]+$ ]] || die "--seeds: expected non-negative integers, got '$s'"
done
[ -z "$SEEDS" ] || [ "$(printf '%s\n' $SEEDS | sort -u | wc -l)" -eq "$(printf '%s\n' $SEEDS | wc -l)" ] ||
  die "--seeds: a seed is named twice in '$SEEDS'"
for kv in "${SETS[@]}"; do
  [ -z "$SEEDS" ] || [[ $kv != train.seed=* ]] || die "--seeds and --set train.seed=... exclude each other"
done
[ "$CONFIGS" = ablation ] && CONFIGS=$ABLATION
[ "$CONFIGS" = coc ] && CONFIGS="default default_nococ"
# The thesis's inputs without the CoC (thesis 4.3.2 no-DOF network).
NOCOC='["radiance:linear", "albedo", "normal:remap01", "depth:scene", "roughness"]'
# The project default's inputs without the CoC.
DEFAULT_NOCOC='["radiance:log1p", "albedo:as_stored", "normal:as_stored", "depth:focal", "roughness:as_stored"]'
# The thesis's inputs with one encoding replaced by the project's (ablation).
inputs_with() {
  local r=radiance:linear n=normal:remap01 d=depth:scene c=coc:thesis
  case $1 in radiance) r=$2 ;; normal) n=$2 ;; depth) d=$2 ;; coc) c=$2 ;; esac
  echo "model.inputs=[\"$r\", \"albedo\", \"$n\", \"$d\", \"roughness\", \"$c\"]"
}
args_of() {
  case $1 in
    thesis) echo "--preset thesis" ;;
    thesis_nococ) echo "--preset thesis" ;;
    default|default_nococ) echo "--preset default" ;;
    thesis_focus) echo "--preset thesis --set loss.focus_weight=4 --set loss.focus_coc_px=1" ;;
    thesis_prefilter) echo "--preset thesis --set data.albedo_prefilter=coc" ;;
    # RAE: recurrent blocks, temporal weight 0.1 (Chaitanya 2017, sec. 5: 0.8 / 0.1 / 0.1).
    thesis_recurrent) echo "--preset thesis --set model.recurrent=true --set loss.temporal=0.1" ;;
    abl_*) echo "--preset thesis" ;;  # its one changed key: extra_of
  esac
}
# Settings with spaces, one per line (passed as --set words by the loop).
extra_of() {
  case $1 in
    thesis_nococ) echo "model.inputs=$NOCOC" ;;
    default) echo "train.warmup_steps=$WARMUP" ;;
    default_nococ) printf '%s\n' "train.warmup_steps=$WARMUP" "model.inputs=$DEFAULT_NOCOC" ;;
    abl_radiance) inputs_with radiance radiance:log1p ;;
    abl_normal) inputs_with normal normal:as_stored ;;
    abl_depth) inputs_with depth depth:focal ;;
    abl_coc) inputs_with coc coc:log ;;
    abl_bottleneck) echo "model.bottleneck_convs=2" ;;
    abl_decoder) echo "model.decoder=project" ;;
    abl_gradloss) echo "loss.log_form=l1" ;;
    abl_schedule) printf '%s\n' "train.schedule=warmup_decay" "train.warmup_steps=$WARMUP" ;;
  esac
}
describe() {
  case $1 in
    thesis) echo "(a) thesis-exact with CoC input" ;;
    thesis_nococ) echo "(b) thesis-exact without CoC input" ;;
    default) echo "(c) project default" ;;
    default_nococ) echo "(c) without CoC input" ;;
    thesis_focus) echo "(d) (a) + focus-weighted loss" ;;
    thesis_prefilter) echo "(d) (a) + CoC albedo prefilter" ;;
    thesis_recurrent) echo "(d) (a) + recurrent + temporal loss" ;;
    abl_radiance) echo "(a) with radiance:log1p" ;;
    abl_normal) echo "(a) with normal:as_stored" ;;
    abl_depth) echo "(a) with depth:focal" ;;
    abl_coc) echo "(a) with coc:log" ;;
    abl_bottleneck) echo "(a) with 2 bottleneck convolutions" ;;
    abl_decoder) echo "(a) with the project's decoder" ;;
    abl_gradloss) echo "(a) with the L1 LoG loss" ;;
    abl_schedule) echo "(a) with warm-up + 0.97^epoch" ;;
  esac
}
for c in $CONFIGS; do
  [ -n "$(describe "$c")" ] || die "--configs: unknown configuration '$c'"
done

if [ -n "$SEEDS" ]; then
  # One study per seed, then the tables across seeds.
  for s in $SEEDS; do
    echo "dof_study.sh: seed $s -> $OUT/seed-$s"
    bash "${BASH_SOURCE[0]}" "${PASS[@]}" --out "$OUT/seed-$s" --set "train.seed=$s"
  done
  described=()
  for c in $CONFIGS; do described+=("$c=$(describe "$c")"); done
  python3 - "$OUT" "$TIME_SIZE" "$SEEDS" "${described[@]}" <<'PY'
import csv, json, math, os, sys

out, side, seeds = sys.argv[1], int(sys.argv[2]), sys.argv[3].split()
label = dict(arg.split("=", 1) for arg in sys.argv[4:])
configs = list(label)
bands = (("in_focus", "< 1 px"), ("coc_1_4", "1–4 px"), ("coc_4_16", "4–16 px"),
         ("coc_16_up", "≥ 16 px"))
def num(v):
    return float("nan") if v is None or v == "" else float(v)
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
pairs = [c for c in configs if c + "_nococ" in label]
if pairs:
    md += ["", "The CoC input's gain (SSIM with it − without it), by CoC band: the mean, then "
           "seed by seed (" + ", ".join(seeds) + "):", "",
           "| pair | " + " | ".join(name for _, name in bands) + " |",
           "| --- " * (len(bands) + 1) + "|"]
    for c in pairs:
        cells = []
        for r, _ in bands:
            g = [ssim(per[(c, s)]["denoised"], r) - ssim(per[(c + "_nococ", s)]["denoised"], r)
                 for s in seeds]
            cells.append(format(mean(g), "+.4f") + " (" + ", ".join(format(x, "+.4f") for x in g) + ")")
        md.append(f"| `{c}` − `{c}_nococ` | " + " | ".join(cells) + " |")
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
with open(os.path.join(out, "results.md.tmp"), "w") as f:
    f.write("\n".join(md) + "\n")
os.replace(os.path.join(out, "results.md.tmp"), os.path.join(out, "results.md"))
# Every seed's rows in one CSV, the seed first.
with open(os.path.join(out, "results.csv.tmp"), "w", newline="") as f:
    w = None
    for s in seeds:
        for c in configs:
            row = per[(c, s)]["csv"]
            if w is None:
                w = csv.writer(f)
                w.writerow(["seed"] + list(row))
            w.writerow([s] + list(row.values()))
os.replace(os.path.join(out, "results.csv.tmp"), os.path.join(out, "results.csv"))
print("\n".join(md))
print(f"dof_study.sh: {out}/results.md, results.csv (across seeds)")
PY
  exit 0
fi

[ "$EPOCHS" -le "$STEPS" ] || EPOCHS=$STEPS
PER_EPOCH=$(( (STEPS + EPOCHS - 1) / EPOCHS ))
TOTAL=$(( EPOCHS * PER_EPOCH ))
mkdir -p "$OUT/runs" "$OUT/reports"

# One data folder for train and eval: the given one, or links to every shard
# of several (named by folder, so that shard-00000.h5 of two jobs do not collide).
if [ ${#DATA[@]} -eq 1 ]; then
  DATA_DIR=$(cd "${DATA[0]}" && pwd)
else
  DATA_DIR=$OUT/data
  mkdir -p "$DATA_DIR"
  for d in "${DATA[@]}"; do
    abs=$(cd "$d" && pwd)
    for s in "$abs"/*.h5; do
      [ -e "$s" ] || continue
      ln -sfn "$s" "$DATA_DIR/$(basename "$abs")-$(basename "$s")"
    done
  done
fi


# The warm-up of the default schedule is 500 steps; a shorter study scales it
# (a tenth of the steps) so that the default is not judged before it warms up.
WARMUP=$(( TOTAL / 10 < 500 ? (TOTAL / 10 > 0 ? TOTAL / 10 : 1) : 500 ))

printf 'dof_study.sh: %d steps per configuration (%d epochs x %d), data %s, out %s\n' \
  "$TOTAL" "$EPOCHS" "$PER_EPOCH" "$DATA_DIR" "$OUT"
for c in $CONFIGS; do
  run=$OUT/runs/$c
  report=$OUT/reports/$c
  if [ -f "$run/study.done" ] && [ "$(cat "$run/study.done")" = "steps $TOTAL" ]; then
    echo "dof_study.sh: $c: trained ($TOTAL steps), not trained again"
  else
    echo "dof_study.sh: $c: training ($(describe "$c")) -> $run"
    # shellcheck disable=SC2046  # args_of gives words
    extra=()
    while IFS= read -r kv; do
      [ -n "$kv" ] && extra+=(--set "$kv")
    done < <(extra_of "$c")
    "$TRAIN" --log-level warn train --data "$DATA_DIR" --run "$run" $(args_of "$c") \
      "${extra[@]}" --set "train.epochs=$EPOCHS" --set "train.steps_per_epoch=$PER_EPOCH" \
      "${SETS[@]}"
    echo "steps $TOTAL" > "$run/study.done.tmp"
    mv "$run/study.done.tmp" "$run/study.done"
  fi
  # A report is made again when its run has trained since, or when it is from
  # before the scores by circle of confusion (no "pixel_share").
  if [ -f "$report/report.json" ] && [ "$report/report.json" -nt "$run/checkpoints/last.pt" ] &&
    grep -q '"pixel_share"' "$report/report.json"; then
    echo "dof_study.sh: $c: evaluated, not evaluated again"
  else
    echo "dof_study.sh: $c: evaluating -> $report"
    rm -rf "$report.tmp"
    # The last weights: every configuration after the same number of steps
    # (best.pt would pick each by its own criterion).
    "$TRAIN" --log-level warn eval --run "$run" --data "$DATA_DIR" --out "$report.tmp" \
      --checkpoint last --images 4 --validation-only --time-size "$TIME_SIZE" \
      --crops "$CROPS" > /dev/null
    rm -rf "$report"
    mv "$report.tmp" "$report"
  fi
  # The CoC probe (eval --coc-override 0): the same weights fed "everything
  # is sharp"; how much each band loses says how much the model uses its CoC.
  probe=$OUT/reports/$c-coc0
  case $c in *_nococ) continue ;; esac
  if [ -f "$probe/report.json" ] && [ "$probe/report.json" -nt "$report/report.json" ]; then
    echo "dof_study.sh: $c: CoC probe done, not made again"
  else
    echo "dof_study.sh: $c: CoC probe (fed CoC 0) -> $probe"
    rm -rf "$probe.tmp"
    "$TRAIN" --log-level warn eval --run "$run" --data "$DATA_DIR" --out "$probe.tmp" \
      --checkpoint last --images 0 --validation-only --crops 0 --coc-override 0 > /dev/null
    rm -rf "$probe"
    mv "$probe.tmp" "$probe"
  fi
done

# The table and the plot.
described=()
for c in $CONFIGS; do described+=("$c=$(describe "$c")"); done
python3 - "$OUT" "$TIME_SIZE" "${described[@]}" <<'PY'
import csv, json, math, os, sys

out, side = sys.argv[1], int(sys.argv[2])
label = dict(arg.split("=", 1) for arg in sys.argv[3:])  # configuration -> describe()
configs = list(label)
cols = ["config", "description", "frames",
        "ssim_all", "ssim_in", "ssim_out", "psnr_all", "psnr_in", "psnr_out",
        "relmse_all", "relmse_in", "relmse_out", "flicker_all", "flicker_in", "flicker_out",
        "ssim_coc_1_4", "ssim_coc_4_16", "ssim_coc_16_up",
        f"ms_per_{side}px_frame", "steps", "train_seconds"]
# The CoC bands of the report (trainer/eval.h, kFocusRegions) beyond in/out.
bands = (("in_focus", "< 1 px"), ("coc_1_4", "1–4 px"), ("coc_4_16", "4–16 px"),
         ("coc_16_up", "≥ 16 px"))
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
            row[f"{m}_{short}"] = float("nan") if v is None else float(v)
    for region, _ in bands[1:]:
        v = d.get(region, {}).get("ssim")
        row[f"ssim_{region}"] = float("nan") if v is None else float(v)
    row["share"] = rep["summary"].get("pixel_share", {})
    t = rep.get("denoise_ms_at_size") or {}
    row[f"ms_per_{side}px_frame"] = float(t.get("ms", float("nan")))
    row["steps"] = steps
    row["train_seconds"] = seconds
    rows.append(row)

def fmt(v, spec):
    return "–" if isinstance(v, float) and not math.isfinite(v) else format(v, spec)

with open(os.path.join(out, "results.csv.tmp"), "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(cols)
    for r in rows:
        w.writerow([r[c] if not isinstance(r[c], float) else repr(r[c]) for c in cols])
os.replace(os.path.join(out, "results.csv.tmp"), os.path.join(out, "results.csv"))

md = ["| configuration | SSIM all | SSIM in focus | SSIM out of focus | PSNR all (dB) | PSNR in | "
      "PSNR out | relMSE all | relMSE in | relMSE out | flicker all | flicker in | flicker out | "
      f"ms / {side}² frame | steps | train wall s |",
      "| --- " * 16 + "|"]
for r in rows:
    md.append("| " + " | ".join([
        f"`{r['config']}` {r['description']}",
        *(fmt(r[f"ssim_{s}"], ".4f") for s in ("all", "in", "out")),
        *(fmt(r[f"psnr_{s}"], ".2f") for s in ("all", "in", "out")),
        *(fmt(r[f"relmse_{s}"], ".4f") for s in ("all", "in", "out")),
        *(fmt(r[f"flicker_{s}"], ".3g") for s in ("all", "in", "out")),
        fmt(r[f"ms_per_{side}px_frame"], ".0f"), str(r["steps"]), fmt(r["train_seconds"], ".0f"),
    ]) + " |")
frames = sorted({r["frames"] for r in rows})
note = (f"\nValidation frames: {', '.join(map(str, frames))}; weights after the last step. "
        "SSIM and PSNR on sRGB clamped to [0, 1]; relative MSE and flicker on linear HDR "
        "(docs/trainer.md, \"Evaluation\"). In focus: CoC < 1 px.\n")
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
for c in configs:
    if c + "_nococ" in by:
        a, b = by[c], by[c + "_nococ"]
        coc_md.append(f"| CoC input: `{c}` − `{c}_nococ` | " +
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
        v = pd.get(region, {}).get("ssim")
        return float("nan") if v is None else float(v)
    probe_rows.append(f"| `{r['config']}` fed CoC 0 | " +
                      " | ".join(fmt(probe_ssim(region) - band_ssim(r, region), "+.4f")
                                 for region, _ in bands) + " |")
if probe_rows:
    coc_md += ["", "The CoC probe (`eval --coc-override 0`): SSIM when the network is fed a CoC of "
               "0 px everywhere (\"all sharp\"), minus SSIM with the frame's own CoC, by the "
               "frame's own CoC band (a model that ignores its CoC input scores +0 everywhere):", "",
               "| configuration | " + " | ".join(name for _, name in bands) + " |",
               "| --- " * (len(bands) + 1) + "|"] + probe_rows
# Side-by-side crops: the windows eval chose from the data's CoC (the same
# for every configuration), copied to OUT/crops/ so that results.md and its
# pictures can be published together.
crops_md = []
first = json.load(open(os.path.join(out, "reports", configs[0], "report.json"))).get("crops", [])
if first:
    import shutil
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
with open(os.path.join(out, "results.md.tmp"), "w") as f:
    f.write("\n".join(md) + "\n" + note + "\n".join(coc_md) + "\n" + "\n".join(crops_md) + "\n")
os.replace(os.path.join(out, "results.md.tmp"), os.path.join(out, "results.md"))

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
with open(os.path.join(out, "results.svg.tmp"), "w") as f:
    f.write("\n".join(svg) + "\n")
os.replace(os.path.join(out, "results.svg.tmp"), os.path.join(out, "results.svg"))
print("\n".join(md) + "\n" + note + "\n".join(coc_md) + "\n")
print(f"dof_study.sh: {out}/results.md, results.csv, results.svg")
PY
