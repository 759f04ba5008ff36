#!/usr/bin/env bash
# deploy/slurm/worker.sbatch under the signal Slurm really sends: scancel
# signals every process of the step at once, the batch shell and any
# subshell it has open (a command substitution) included. Whatever the
# script is doing at that moment, the element must end with its exit file
# saying reason=signal, after its worker was told to stop.
#
# The worker here is a stand-in that records the SIGTERM it gets, so the
# test can signal the script at many moments in a few seconds; the real
# worker under a real Slurm is tests/slurm/test_slurm.sh.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
script=$here/../../deploy/slurm/worker.sbatch
T=$(mktemp -d /tmp/dofarm-worker-signals.XXXXXX)
trap 'rm -rf "$T"' EXIT
fail() {
  echo "FAIL: $*" >&2
  echo "--- script output:" >&2; cat "$out/log" >&2 || true
  echo "--- stand-in log:" >&2; cat "$STANDIN_LOG" >&2 || true
  exit 1
}

cat >"$T/stand-in" <<'STUB'
#!/usr/bin/env bash
# Notes that it started, then runs until SIGTERM, which it notes too.
trap 'echo "stopped by TERM" >>"$STANDIN_LOG"; exit 0' TERM
trap 'echo "exiting: $?" >>"$STANDIN_LOG"' EXIT
echo "started: $*" >>"$STANDIN_LOG"
while :; do sleep 0.005; done
STUB
chmod +x "$T/stand-in"

rounds=${ROUNDS:-60}
early=0
for i in $(seq 1 "$rounds"); do
  out=$T/out-$i
  mkdir -p "$out/.dofarm-state"
  echo "127.0.0.1:1" >"$out/.dofarm-state/endpoint"
  export STANDIN_LOG=$out/stand-in.log
  # A new session makes the script the leader of a process group that can be
  # signalled as a whole, as slurmstepd signals a step.
  DOFARM=$T/stand-in DOFARM_SLURM_OUT=$out DOFARM_SLURM_POLL=0.002 \
    SLURM_ARRAY_JOB_ID=7 SLURM_ARRAY_TASK_ID=$i setsid bash "$script" >"$out/log" 2>&1 &
  leader=$!
  # Wait until the stand-in runs, then a moment more that differs per round.
  for _ in $(seq 1 400); do [ -s "$STANDIN_LOG" ] && break; sleep 0.005; done
  [ -s "$STANDIN_LOG" ] || fail "round $i: the worker never started"
  sleep "0.0$((i % 10))$((i % 7))"
  kill -TERM -- "-$leader" 2>/dev/null || true
  rc=0
  wait "$leader" || rc=$?
  f=$out/.dofarm-slurm/elements/7_$i.exit
  [ -f "$f" ] || fail "round $i: no exit file after SIGTERM to the element (script rc=$rc)"
  line=$(cat "$f")
  if ! grep -q "stopped by TERM" "$STANDIN_LOG"; then
    # The stand-in ended before the signal came (seen once in several
    # hundred rounds on a loaded machine): then the element must say so,
    # with the worker's own status, and the round tests nothing else.
    own=$(sed -n 's/^exiting: //p' "$STANDIN_LOG" | tail -n 1)
    [[ -n $own && $line == "rc=$own reason=exit host="* ]] ||
      fail "round $i: the worker ended by itself (status ${own:-unknown}) but the exit file says '$line'"
    early=$((early + 1))
    continue
  fi
  [[ $line == "rc=0 reason=signal host="* ]] || fail "round $i: exit file says '$line', expected rc=0 reason=signal"
done
[ "$early" -le $((rounds / 10)) ] || fail "in $early of $rounds rounds the worker ended before the signal"
echo "worker.sbatch recorded reason=signal in $((rounds - early)) of $rounds rounds ($early rounds: the worker ended first, recorded as such)"
