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
#   default_nococ_wide   (c) without the CoC input at the CoC network's widths
#                        (36..113), which separates the CoC's information from width
#   thesis_prefilter_nococ  (d) prefilter without the CoC input, at (a)'s widths:
#                        what the CoC input adds once the albedo is blurred by it
#   default_prefilter    (c) + CoC-sized albedo prefilter (the courtyard's best)
#   default_prefilter_nococ_wide  the same without the CoC input, (c)'s CoC widths
# and the same pair with a depth input that carries no focus information
# (depth:focal is 0.5 on the focal plane, so with it the CoC is known up to
# one factor per frame; --configs sdepth: default_sdepth default_sdepth_nococ):
#   default_sdepth        (c) with depth:scene, z / 5
#   default_sdepth_nococ  (c) with depth:scene and without the CoC input
# and write one table (OUT/results.md, OUT/results.csv) with, per
# configuration, SSIM / PSNR / relative MSE over all, in-focus and
# out-of-focus pixels, flicker, ms per 512² frame, training steps and wall
# time, and one plot of error against time (OUT/results.svg). Scores are on
# the validation frames of the run's split (the same frames for every
# configuration: the split is drawn from the shards' content).
#
#   bench/trainer/dof_study.sh [--steps N] [--out DIR] [--epochs E] [--time-size S] [--crops K]
#                              [--configs "thesis default ..."] [--seeds "1 2 3"] [--train-only]
#                              [--held-out DIR]... [--set KEY=VALUE]... [DATA_DIR...]
#
# --train-only: train every configuration (resumably, as always) and stop:
# no evaluation, no table. For a machine that trains (a GPU node) while the
# frames the networks are judged on are elsewhere; the same command without
# it, where those frames are, then scores the runs it finds trained.
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
# a smoke run). Environment: DOFARM_TRAIN (default build/dofarm-train),
# DOFARM (default build/dofarm, for the held-out check).
#
# --held-out DIR: a farm output folder of frames that no configuration trains
# on, rendered with references cleaner than the training shards' (e.g. the
# study job over frames outside the training range at its own reference
# setting, while the training shards cap their references: the targets a
# network learns from may be noisy, the ones it is judged by may not). Every
# configuration is also evaluated over all of DIR's frames
# (OUT/reports-held-out/NAME), and results.md gets a second table with the
# reference ceiling of those frames. With --set data.val_fraction=0 (every
# rendered frame trains) the held-out frames are what the main table, the
# crops and the CoC probe score. Refused when a held-out shard shares a
# frame with a training shard of the same scene and seed. --held-out may be
# given several times (e.g. one `dofarm run` per held-out frame): the
# folders are joined in OUT/held-out-data by symbolic links. When the set of
# held-out shards changes (a folder more, a shard rendered again), every
# report that scored them is made again (OUT/held-out.sig lists them).
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
TRAIN_ONLY=0
HELD_OUT=""
HELD_DIRS=()
DOFARM=${DOFARM:-$ROOT/build/dofarm}
PASS=()  # the arguments each seed's study gets (all but --seeds and --out)
usage() { sed -n '2,59p' "$0" | sed 's/^# \{0,1\}//'; }
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
    --train-only) TRAIN_ONLY=1; PASS+=("$1"); shift ;;
    --held-out) HELD_DIRS+=("${2:?}"); PASS+=("$1" "$2"); shift 2 ;;
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
for d in "${HELD_DIRS[@]}"; do
  [ -d "$d" ] || die "--held-out: no data folder $d"
done
# join_shards DEST named|numbered DIR...: DEST holds links to every shard of
# the DIRs and nothing else, named FOLDER-SHARD (numbered: I-FOLDER-SHARD, I
# the DIR's place in the list; named turns to numbered when two DIRs share
# a folder name, such as two frame ranges of one job rendered as farm
# outputs of their own, out/a/courtyard and out/b/courtyard). The links are
# made in a folder of their own and renamed into place one by one (each
# rename atomic, so that studies started side by side on one OUT, as
# cuda_node.sh does, never see a link missing); links of an earlier call
# that are not among them go.
join_shards() {
  local dest=$1 how=$2 i=0 d abs s name fresh l
  shift 2
  [ -n "$(for d in "$@"; do basename "$(cd "$d" && pwd)"; done | sort | uniq -d)" ] && how=numbered
  mkdir -p "$dest"
  fresh=$(mktemp -d "$(dirname "$dest")/.links.XXXXXX")
  for d in "$@"; do
    abs=$(cd "$d" && pwd)
    for s in "$abs"/*.h5; do
      [ -e "$s" ] || continue
      name=$(basename "$abs")-$(basename "$s")
      [ "$how" = numbered ] && name=$i-$name
      ln -sfn "$s" "$fresh/$name"
    done
    i=$((i + 1))
  done
  for l in "$dest"/*; do
    [ -e "$l" ] || [ -L "$l" ] || continue
    [ -L "$fresh/$(basename "$l")" ] || rm -f "$l"
  done
  for l in "$fresh"/*; do
    [ -L "$l" ] && mv -f "$l" "$dest/"
  done
  rmdir "$fresh"
}
if [ ${#HELD_DIRS[@]} -eq 1 ] && [ -z "$SEEDS" ]; then
  HELD_OUT=$(cd "${HELD_DIRS[0]}" && pwd)
elif [ ${#HELD_DIRS[@]} -gt 0 ] && [ -z "$SEEDS" ]; then
  # Several folders: one folder of links to them alone, so that a folder
  # left out this time is not scored. Each link is named by the folder's
  # place in the argument list, as held-out folders often share a name (cornell).
  HELD_OUT=$OUT/held-out-data
  join_shards "$HELD_OUT" numbered "${HELD_DIRS[@]}"
fi
if [ -n "$HELD_OUT" ]; then
  [ -x "$DOFARM" ] || die "--held-out: $DOFARM not found (it reads the shards' frames); set DOFARM"
  python3 "$ROOT/bench/trainer/study_tables.py" held-out-check "$DOFARM" "$HELD_OUT" "${DATA[@]}" ||
    die "--held-out: $HELD_OUT cannot serve as held-out frames (above)"
fi
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
[ "$CONFIGS" = sdepth ] && CONFIGS="default_sdepth default_sdepth_nococ"
# The thesis's inputs without the CoC (thesis 4.3.2 no-DOF network).
NOCOC='["radiance:linear", "albedo", "normal:remap01", "depth:scene", "roughness"]'
# The encoder widths of the thesis's DOF network (thesis 4.3.2), which the
# CoC input's networks have: a no-CoC network at these widths differs from
# its CoC twin only by the first convolution's CoC column.
DOF_WIDTHS='[36, 48, 64, 85, 113]'
# The project default's inputs without the CoC.
DEFAULT_NOCOC='["radiance:log1p", "albedo:as_stored", "normal:as_stored", "depth:focal", "roughness:as_stored"]'
# The project default's inputs with the thesis's scene depth, with and without the CoC.
SDEPTH='["radiance:log1p", "albedo:as_stored", "normal:as_stored", "depth:scene", "roughness:as_stored", "coc:log"]'
SDEPTH_NOCOC='["radiance:log1p", "albedo:as_stored", "normal:as_stored", "depth:scene", "roughness:as_stored"]'
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
    default|default_nococ|default_nococ_wide|default_sdepth|default_sdepth_nococ)
      echo "--preset default" ;;
    default_prefilter|default_prefilter_nococ_wide) echo "--preset default --set data.albedo_prefilter=coc" ;;
    thesis_focus) echo "--preset thesis --set loss.focus_weight=4 --set loss.focus_coc_px=1" ;;
    thesis_prefilter|thesis_prefilter_nococ) echo "--preset thesis --set data.albedo_prefilter=coc" ;;
    # RAE: recurrent blocks, temporal weight 0.1 (Chaitanya 2017, sec. 5: 0.8 / 0.1 / 0.1).
    thesis_recurrent) echo "--preset thesis --set model.recurrent=true --set loss.temporal=0.1" ;;
    abl_*) echo "--preset thesis" ;;  # its one changed key: extra_of
  esac
}
# Settings with spaces, one per line (passed as --set words by the loop).
extra_of() {
  case $1 in
    thesis_nococ) echo "model.inputs=$NOCOC" ;;
    default|default_prefilter) echo "train.warmup_steps=$WARMUP" ;;
    default_nococ) printf '%s\n' "train.warmup_steps=$WARMUP" "model.inputs=$DEFAULT_NOCOC" ;;
    default_nococ_wide|default_prefilter_nococ_wide)
      printf '%s\n' "train.warmup_steps=$WARMUP" "model.inputs=$DEFAULT_NOCOC" "model.channels=$DOF_WIDTHS"
      ;;
    thesis_prefilter_nococ) printf '%s\n' "model.inputs=$NOCOC" "model.channels=$DOF_WIDTHS" ;;
    default_sdepth) printf '%s\n' "train.warmup_steps=$WARMUP" "model.inputs=$SDEPTH" ;;
    default_sdepth_nococ) printf '%s\n' "train.warmup_steps=$WARMUP" "model.inputs=$SDEPTH_NOCOC" ;;
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
    default_nococ_wide) echo "(c) without CoC input, the CoC network's widths" ;;
    thesis_prefilter_nococ) echo "(d) prefilter without CoC input, (a)'s widths" ;;
    default_prefilter) echo "(c) + CoC albedo prefilter" ;;
    default_prefilter_nococ_wide) echo "(c) + prefilter, without CoC input, the CoC network's widths" ;;
    default_sdepth) echo "(c) with depth:scene" ;;
    default_sdepth_nococ) echo "(c) with depth:scene, without CoC input" ;;
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
  [ "$TRAIN_ONLY" = 1 ] && exit 0
  described=()
  for c in $CONFIGS; do described+=("$c=$(describe "$c")"); done
  python3 "$ROOT/bench/trainer/study_tables.py" seeds "$OUT" "$TIME_SIZE" "$SEEDS" "${described[@]}"
  exit 0
fi

# Reports of held-out frames stand for the set they scored: when that set
# changes (a folder more or less, a shard rendered again), they go.
if [ -n "$HELD_OUT" ]; then
  sig=$(for s in "$HELD_OUT"/*.h5; do
    [ -e "$s" ] || continue
    r=$(readlink -f "$s")
    echo "$r $(stat -c '%s %Y' "$r")"
  done)
  if [ ! -f "$OUT/held-out.sig" ] || [ "$(cat "$OUT/held-out.sig")" != "$sig" ]; then
    stale=()
    [ -d "$OUT/reports-held-out" ] && stale+=("$OUT/reports-held-out")
    for r in "$OUT"/reports/*/report.json; do
      [ -f "$r" ] && grep -q '"held_out": true' "$r" && stale+=("$(dirname "$r")")
    done
    if [ ${#stale[@]} -gt 0 ]; then
      echo "dof_study.sh: the held-out frames changed; their reports are made again"
      rm -rf "${stale[@]}"
    fi
    mkdir -p "$OUT"
    printf '%s\n' "$sig" > "$OUT/held-out.sig.tmp"
    mv "$OUT/held-out.sig.tmp" "$OUT/held-out.sig"
  fi
fi

[ "$EPOCHS" -le "$STEPS" ] || EPOCHS=$STEPS
PER_EPOCH=$(( (STEPS + EPOCHS - 1) / EPOCHS ))
TOTAL=$(( EPOCHS * PER_EPOCH ))
mkdir -p "$OUT/runs" "$OUT/reports"

# One data folder for train and eval: the given one, or links to every shard
# of several (named by folder, so that shard-00000.h5 of two jobs do not
# collide; numbered when folders share a name: join_shards).
if [ ${#DATA[@]} -eq 1 ]; then
  DATA_DIR=$(cd "${DATA[0]}" && pwd)
else
  DATA_DIR=$OUT/data
  join_shards "$DATA_DIR" named "${DATA[@]}"
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
  [ "$TRAIN_ONLY" = 1 ] && continue
  # What the main table scores: the run's validation frames, or, for a run
  # without any (data.val_fraction = 0, to train on every rendered frame),
  # the held-out frames.
  if python3 -c 'import json, sys; sys.exit(0 if any(v["val"][1] > v["val"][0] for v in json.load(open(sys.argv[1]))["shards"].values()) else 1)' "$run/split.json"; then
    score=(--data "$DATA_DIR" --validation-only)
    held_separately=1
  else
    [ -n "$HELD_OUT" ] ||
      die "$c: the run has no validation frames (data.val_fraction = 0?) and there is no --held-out folder to score"
    score=(--data "$HELD_OUT" --validation-only --held-out)
    held_separately=0
  fi
  # A report is made again when its run has trained since, or when it is from
  # before the scores by circle of confusion (no "pixel_share") or before the
  # SSIM per tile that the CoC input's interval needs (no "denoised_tiles").
  if [ -f "$report/report.json" ] && [ "$report/report.json" -nt "$run/checkpoints/last.pt" ] &&
    grep -q '"pixel_share"' "$report/report.json" && grep -q '"denoised_tiles"' "$report/report.json"; then
    echo "dof_study.sh: $c: evaluated, not evaluated again"
  else
    echo "dof_study.sh: $c: evaluating -> $report"
    rm -rf "$report.tmp"
    # The last weights: every configuration after the same number of steps
    # (best.pt would pick each by its own criterion).
    "$TRAIN" --log-level warn eval --run "$run" "${score[@]}" --out "$report.tmp" \
      --checkpoint last --images 4 --time-size "$TIME_SIZE" --crops "$CROPS" > /dev/null
    rm -rf "$report"
    mv "$report.tmp" "$report"
  fi
  # The held-out frames at clean references: all of them, the same weights.
  held=$OUT/reports-held-out/$c
  if [ -n "$HELD_OUT" ] && [ "$held_separately" = 1 ]; then
    if [ -f "$held/report.json" ] && [ "$held/report.json" -nt "$run/checkpoints/last.pt" ]; then
      echo "dof_study.sh: $c: held-out frames evaluated, not evaluated again"
    else
      echo "dof_study.sh: $c: evaluating the held-out frames -> $held"
      mkdir -p "$OUT/reports-held-out"
      rm -rf "$held.tmp"
      "$TRAIN" --log-level warn eval --run "$run" --data "$HELD_OUT" --out "$held.tmp" \
        --checkpoint last --images 4 --validation-only --held-out --crops "$CROPS" > /dev/null
      rm -rf "$held"
      mv "$held.tmp" "$held"
    fi
  fi
  # The CoC probe (eval --coc-override 0): the same weights fed "everything
  # is sharp"; how much each band loses says how much the model uses its CoC.
  probe=$OUT/reports/$c-coc0
  case $c in *_nococ | *_nococ_wide) continue ;; esac
  if [ -f "$probe/report.json" ] && [ "$probe/report.json" -nt "$report/report.json" ]; then
    echo "dof_study.sh: $c: CoC probe done, not made again"
  else
    echo "dof_study.sh: $c: CoC probe (fed CoC 0) -> $probe"
    rm -rf "$probe.tmp"
    "$TRAIN" --log-level warn eval --run "$run" "${score[@]}" --out "$probe.tmp" \
      --checkpoint last --images 0 --crops 0 --coc-override 0 > /dev/null
    rm -rf "$probe"
    mv "$probe.tmp" "$probe"
  fi
done

[ "$TRAIN_ONLY" = 1 ] && { echo "dof_study.sh: trained; --train-only: not scored"; exit 0; }
# The table and the plot.
described=()
for c in $CONFIGS; do described+=("$c=$(describe "$c")"); done
python3 "$ROOT/bench/trainer/study_tables.py" study "$OUT" "$TIME_SIZE" "${described[@]}"
