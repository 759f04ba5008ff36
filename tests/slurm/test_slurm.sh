#!/usr/bin/env bash
# tests/slurm/test_slurm.sh DOFARM_EXECUTABLE
#
# Proves that deploy/slurm/dofarm-slurm renders a batch on a real Slurm with
# the same bytes as `dofarm run`, although a worker is cancelled mid-task:
#  1. starts a private munged and a one-node Slurm (slurmctld + slurmd on
#     "localhost", 2 CPUs) on free ports, everything under a temp folder;
#  2. submits a small Cornell job with 2 workers; the coordinator is a
#     Slurm job too;
#  3. waits until a worker element holds a task and scancels that element:
#     its worker must hand the task back (its log says so) and its exit file
#     must say "signal"; `dofarm-slurm resubmit` must pick exactly that
#     element (unless the batch has already ended);
#  4. waits for the batch to end "done", for every worker element to end by
#     itself, and for the coordinator job to stop;
#  5. renders the same job with `dofarm run` and compares every shard's data
#     checksum as recomputed by `dofarm inspect --json` (the files differ in
#     timestamps and batch ids; the data may not);
#  6. submits a second batch with the coordinator on the submit host and
#     cancels it: no job may be left and the coordinator process must end.
# Every daemon it started is stopped by PID on exit.
#
# Exit 77 (skipped) when not root or Slurm/munge are not installed, unless
# CI=true, where that is a failure.
set -euo pipefail

skip() {
  if [ "${CI:-}" = true ]; then
    echo "FAIL: $* (CI=true: the Slurm test may not be skipped; run scripts/install-deps.sh as root)"
    exit 1
  fi
  echo "SKIP: $*"
  exit 77
}
fail() {
  echo "FAIL: $*"
  exit 1
}
log() { echo "[$(date +%T)] $*"; }

[ $# -eq 1 ] || {
  echo "usage: $0 DOFARM_EXECUTABLE" >&2
  exit 2
}
dofarm=$(readlink -f "$1")
[ -x "$dofarm" ] || fail "$1 is not an executable"
[ "$(id -u)" -eq 0 ] || skip "needs root to run slurmd and munged"
for b in slurmctld slurmd munged sbatch squeue scancel sinfo python3; do
  command -v "$b" >/dev/null || skip "$b is not installed (scripts/install-deps.sh installs slurm-wlm and munge)"
done

repo=$(cd "$(dirname "$(readlink -f "${BASH_SOURCE[0]}")")/../.." && pwd)
dofarm_slurm=$repo/deploy/slurm/dofarm-slurm
scene=$repo/jobs/scenes/cornell.gltf
[ -f "$scene" ] || fail "no $scene"

T=$(mktemp -d /tmp/dofarm-slurm-test.XXXXXX)
chmod 755 "$T" # munged wants its socket's folder executable for all
local_coord_pid=""

# Alive and not a zombie (a daemon whose parent does not reap it).
running() {
  kill -0 "$1" 2>/dev/null && ! grep -q '^State:.*Z' "/proc/$1/status" 2>/dev/null
}

cleanup() {
  local rc=$?
  set +e
  trap - EXIT
  if [ -f "$T/slurm.conf" ] && [ -f "$T/slurmctld.pid" ]; then
    # Jobs first: slurmstepd and job processes outlive slurmd.
    scancel --full --quiet -u root 2>/dev/null
    for _ in $(seq 1 40); do
      [ -z "$(squeue -h 2>/dev/null)" ] && break
      sleep 0.25
    done
  fi
  [ -z "$local_coord_pid" ] || kill -TERM "$local_coord_pid" 2>/dev/null
  local d pid
  for d in slurmd slurmctld munged; do
    [ -f "$T/$d.pid" ] || continue
    pid=$(cat "$T/$d.pid")
    kill -TERM "$pid" 2>/dev/null
    # Daemons save state as they stop; wait before removing their folders.
    for _ in $(seq 1 40); do
      running "$pid" || break
      sleep 0.25
    done
  done
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 77 ]; then
    echo "--- logs of the failed run (kept in $T) ---"
    for f in "$T"/log/*.log "$T"/farm/.dofarm-slurm/logs/*.log "$T"/farm/.dofarm-slurm/elements/*; do
      [ -f "$f" ] && {
        echo "== $f"
        tail -n 30 "$f"
      }
    done
  elif [ -z "${KEEP_SLURM_TEST:-}" ]; then
    rm -rf "$T"
  fi
  exit "$rc"
}
trap cleanup EXIT

free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# ------------------------------------------------------------- munge
mkdir -p "$T/munge" "$T/state" "$T/spool" "$T/log"
chmod 700 "$T/munge"
dd if=/dev/urandom of="$T/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$T/munge/munge.key"
munged --socket="$T/munge.socket" --key-file="$T/munge/munge.key" \
  --pid-file="$T/munged.pid" --log-file="$T/log/munged.log" \
  --seed-file="$T/munge/munged.seed" || fail "munged did not start (see $T/log/munged.log)"
log "munged running (pid $(cat "$T/munged.pid"))"

# ------------------------------------------------------------- slurm
cat >"$T/slurm.conf" <<EOF
ClusterName=dofarmtest
SlurmctldHost=localhost
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$T/munge.socket,cred_expire=10
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/log/slurmctld.log
SlurmdLogFile=$T/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
SchedulerParameters=batch_sched_delay=0,sched_min_interval=0
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
KillWait=10
MinJobAge=300
InactiveLimit=0
NodeName=localhost CPUs=2 RealMemory=500 State=UNKNOWN
# The coordinator job needs almost no CPU: two jobs may share a core.
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP OverSubscribe=FORCE:2
EOF
export SLURM_CONF=$T/slurm.conf
slurmctld -f "$SLURM_CONF" || fail "slurmctld did not start (see $T/log/slurmctld.log)"
slurmd -N localhost -f "$SLURM_CONF" || fail "slurmd did not start (see $T/log/slurmd.log)"
for i in $(seq 1 120); do
  [ "$(sinfo -h -n localhost -o %t 2>/dev/null)" = idle ] && break
  [ "$i" -lt 120 ] || fail "the node did not become idle: $(sinfo 2>&1)"
  sleep 0.25
done
log "slurm running: $(sinfo -h -o '%P %a %D %t %N')"

# ------------------------------------------------------------- the job
# Small, but a render task (one 64x48 tile = 12 blocks of 16x16 pixels, and
# a worker notices SIGTERM between blocks) takes a few seconds on one
# thread, so that a worker can be cancelled in the middle of one.
cat >"$T/job.toml" <<EOF
scene = "$scene"
seed = 3

[image]
width = 64
height = 48

[frames]
start = 0
end = 5
per_shard = 2

[[camera.key]]
frame = 0
position = [0.0, 1.0, 3.9]
look_at = [0.0, 1.0, 0.0]
fov = 38.0
focal_distance = 3.55
aperture = 0.05

[buffers]
versions = 2
reference_spp = 512
albedo_ref_spp = 2

[farm]
tile = 64
EOF

# Quick reactions for a test: the element scripts look for the end of the
# batch every second, the coordinator stops 5 s after it (sbatch passes the
# environment on).
export DOFARM_SLURM_POLL=1 DOFARM_SLURM_LINGER=5
# Workers reach the coordinator by the node's host name; a container whose
# name does not resolve uses the loopback address (the node is this machine).
getent hosts "$(hostname)" >/dev/null || export DOFARM_SLURM_HOST=127.0.0.1
out=$T/farm
start=$SECONDS
# Training options without training are bad input, before anything is submitted.
rc=0
"$dofarm_slurm" submit "$T/job.toml" --workers 1 --out "$T/notrain" --dofarm "$dofarm" \
  --train-gres gpu:1 2>"$T/notrain.err" || rc=$?
[ "$rc" -eq 2 ] || fail "--train-gres without --train: exit $rc, expected 2 ($(cat "$T/notrain.err"))"
# Somebody else's job in the queue (held, so it never runs): status must not list it.
foreign=$(sbatch --parsable --hold --job-name=not-ours --output=/dev/null --wrap "sleep 600")
foreign=${foreign%%;*}
# The training job gets its own resources (--train-*); `true` stands in for
# dofarm-train, which this build may lack.
batch=$("$dofarm_slurm" submit "$T/job.toml" --workers 2 --out "$out" --dofarm "$dofarm" \
  --cpus-per-task 1 --endpoint-timeout 60 --train --dofarm-train "$(type -P true)" \
  --train-partition debug --train-cpus-per-task 1 --train-sbatch-arg=--comment=dofarm-train-test) ||
  fail "dofarm-slurm submit failed"
log "submitted batch $batch"

# ------------------------------------------------------------- cancel a worker mid-task
# A worker logs "task N: frame F tile ..." when it starts rendering; the
# element whose last log line is that is in the middle of a task.
victim=""
for _ in $(seq 1 600); do
  for f in "$out"/.dofarm-slurm/logs/worker-*.log; do
    [ -f "$f" ] || continue
    last=$(tail -n 1 "$f")
    if [[ $last =~ \]\ task\ [0-9]+:\ frame\  ]]; then
      victim=$(basename "$f" .log)
      victim=${victim#worker-}
      break 2
    fi
  done
  sleep 0.1
done
[ -n "$victim" ] || fail "no worker element started a task within 60 s: $("$dofarm_slurm" status "$out")"
log "worker element $victim: $(tail -n 1 "$out/.dofarm-slurm/logs/worker-$victim.log"); scancel $victim"
scancel "$victim"
for i in $(seq 1 240); do
  [ -f "$out/.dofarm-slurm/elements/$victim.exit" ] && break
  [ "$i" -lt 240 ] || fail "element $victim wrote no exit file within 60 s"
  sleep 0.25
done
# The submission's records and status, checked after the victim is chosen:
# on a loaded machine these checks took long enough that the whole batch
# had rendered before the look for a task in progress began.
state_json=$out/.dofarm-slurm/state.json
[ -f "$state_json" ] || fail "no $state_json"
coord_job=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["coordinator_job"])' "$state_json")
array_job=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["arrays"][0]["job_id"])' "$state_json")
train_job=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["train_job"])' "$state_json")
{ [ -n "$coord_job" ] && [ -n "$array_job" ] && [ -n "$train_job" ]; } ||
  fail "state.json lacks job ids: $(cat "$state_json")"
train_info=$(scontrol show job "$train_job")
grep -q "Comment=dofarm-train-test" <<<"$train_info" || fail "training job lacks its own sbatch args: $train_info"
grep -q "NumCPUs=1 " <<<"$train_info" || fail "training job lacks --cpus-per-task 1: $train_info"

status_json() { "$dofarm_slurm" status "$out" --json; }
jq_py() { python3 -c "import json,sys; d=json.load(sys.stdin); $1"; }
listed=$(status_json | jq_py 'print(" ".join(sorted(set(j["array_job_id"] or j["job_id"] for j in d["slurm"]["jobs"]))), d["slurm"]["source"].split()[1])')
[[ " $listed " != *" $foreign "* ]] || fail "status lists job $foreign, which is not this submission's: $listed"
[[ $listed == *"--me" ]] || fail "status did not ask squeue for this user's jobs only: $listed"
scancel "$foreign"

exit_line=$(cat "$out/.dofarm-slurm/elements/$victim.exit")
log "element $victim: $exit_line"
[[ $exit_line == "rc=0 reason=signal"* ]] || fail "element $victim: expected 'rc=0 reason=signal', got '$exit_line'"
victim_log=$out/.dofarm-slurm/logs/worker-$victim.log
task_no=$(sed -n 's/.*\] task \([0-9]*\): frame .*/\1/p' "$victim_log" | tail -n 1)
if ! grep -q "task $task_no: stopping; handing the task back" "$victim_log"; then
  # On a loaded machine the task can end between the look at the log and
  # the signal. Then the coordinator must hold it as done by this element.
  by=$("$dofarm" status "$batch" --tasks --json --coordinator "tcp://$(cat "$out/.dofarm-state/endpoint" 2>/dev/null)" 2>/dev/null |
    jq_py "t=[t for t in d['batches'][0]['tasks'] if t['task']==$task_no]; print(t[0]['state'], t[0]['worker']) if t else print('missing')" 2>/dev/null) ||
    by="status failed"
  # Later still, the batch has ended and its coordinator stopped (5 s after
  # the end) before this look: then every task is done, this one included.
  if [[ $by == "status failed" && $(cat "$out/.dofarm-slurm/finished" 2>/dev/null) == done ]]; then
    log "the batch ended and its coordinator stopped before the look at task $task_no; the hand-back was not exercised in this run"
  else
    [[ $by == "done slurm-$victim-"* ]] ||
      fail "the cancelled worker neither handed task $task_no back nor finished it (coordinator: $by): $(tail -5 "$victim_log")"
    log "element $victim had finished task $task_no before the signal; the hand-back was not exercised in this run"
  fi
fi

resub=$("$dofarm_slurm" resubmit "$out" 2>&1) || fail "dofarm-slurm resubmit failed: $resub"
log "resubmit: $resub"
if [[ $resub == *"resubmitting"* ]]; then
  grep -q "resubmitting 1 failed elements .*: $victim\$" <<<"$resub" ||
    fail "resubmit should pick exactly $victim: $resub"
else
  [[ $resub == *"is done; nothing to resubmit"* ]] || fail "unexpected resubmit answer: $resub"
fi

# ------------------------------------------------------------- the batch ends
for i in $(seq 1 480); do
  [ -f "$out/.dofarm-slurm/finished" ] && break
  [ "$i" -lt 480 ] || fail "the batch did not end within 120 s: $("$dofarm_slurm" status "$out")"
  sleep 0.25
done
final=$(status_json)
state=$(jq_py 'print(d["dofarm"]["batch"]["state"])' <<<"$final")
log "batch $batch ended: $state after $((SECONDS - start)) s"
[ "$state" = "done" ] || fail "batch state $state, expected done: $("$dofarm_slurm" status "$out")"
"$dofarm_slurm" status "$out"

# Every job leaves the queue by itself: workers go home, the coordinator stops.
for i in $(seq 1 160); do
  left=$(squeue -h -o '%i %T %j')
  [ -z "$left" ] && break
  [ "$i" -lt 160 ] || fail "jobs still queued 40 s after the batch ended: $left"
  sleep 0.25
done
n_finished=$(grep -l 'reason=finished' "$out"/.dofarm-slurm/elements/*.exit | wc -l)
[ "$n_finished" -ge 1 ] || fail "no worker element ended with reason=finished"
[ ! -e "$out/.dofarm-state/endpoint" ] || fail "the stopped coordinator left its endpoint file"
after=$("$dofarm_slurm" status "$out" --json | jq_py 'print(d["dofarm"]["source"].split()[0], d["dofarm"]["batch"]["state"])')
[ "$after" = "final-status.json done" ] || fail "status after the coordinator stopped: $after"
log "all jobs ended; $n_finished worker elements ended with the batch"

# ------------------------------------------------------------- same bytes as dofarm run
"$dofarm" run "$T/job.toml" --out "$T/ref" --workers 2 --log-level warn >/dev/null ||
  fail "dofarm run of the same job failed"
checksum() {
  "$dofarm" inspect "$1" --json | jq_py '
c = d["data_checksum"]
assert c["ok"], "stored and recomputed data checksums differ"
print(c["computed"])'
}
shards=$(cd "$T/ref" && ls shard-*.h5)
[ "$(cd "$out" && ls shard-*.h5)" = "$shards" ] ||
  fail "different shard files: ref [$shards] slurm [$(cd "$out" && ls shard-*.h5)]"
for s in $shards; do
  a=$(checksum "$T/ref/$s") || fail "inspect $T/ref/$s"
  b=$(checksum "$out/$s") || fail "inspect $out/$s"
  [ "$a" = "$b" ] || fail "$s: data checksum $b on Slurm, $a from dofarm run"
  log "$s: $b (same as dofarm run)"
done

# ------------------------------------------------------------- coordinator on the submit host, cancel
out2=$T/farm2
batch2=$("$dofarm_slurm" submit "$T/job.toml" --workers 2 --out "$out2" --dofarm "$dofarm" \
  --coordinator-on-submit-host --endpoint-timeout 30 --set frames.end=99) ||
  fail "dofarm-slurm submit --coordinator-on-submit-host failed"
local_coord_pid=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["coordinator_pid"])' \
  "$out2/.dofarm-slurm/state.json")
kill -0 "$local_coord_pid" || fail "the local coordinator (pid $local_coord_pid) is not running"
log "batch $batch2: coordinator pid $local_coord_pid on this host; cancelling"
"$dofarm_slurm" cancel "$out2" || fail "dofarm-slurm cancel failed"
for i in $(seq 1 120); do
  left=$(squeue -h -o '%i %T %j')
  gone=1
  running "$local_coord_pid" && gone=""
  [ -z "$left" ] && [ -n "$gone" ] && break
  [ "$i" -lt 120 ] || fail "after cancel: jobs [$left], coordinator process alive: ${gone:-yes}"
  sleep 0.25
done
log "batch $batch2 cancelled: no jobs left, the coordinator process ended"
local_coord_pid=""

log "PASS in $((SECONDS - start)) s"
