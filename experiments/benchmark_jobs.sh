#!/bin/bash
# The wedges benchmark's jobs on one GPU host, in stages. From the repository root:
#   OUT=/tmp/out RUNS=/tmp/runs STAGE=screen bash experiments/benchmark_jobs.sh
#   OUT=... RUNS=... STAGE=tune bash experiments/benchmark_jobs.sh
#   OUT=... RUNS=... STAGE=run OBJECTS="wedge_0 wedge_6" bash experiments/benchmark_jobs.sh
#   OUT=... RUNS=... STAGE=rerun OBJECT=wedge_0 LEARNER=sern bash experiments/benchmark_jobs.sh
# screen: the selection screen of the family, the confirmation screen of its candidates, the
#         benchmark file by the pre-registered rule ($RUNS/wedges.json), and the simulator
#         checks (time step, MJX) on the scored objects;
# tune:   the tuning grid (five settings side by side) and extensions of edge choices, then
#         $OUT/tuned.json;
# run:    one part per object (all learners, all seeds), PARALLEL parts side by side, each on
#         its share of the cores, the parts spread over the GPUs;
# rerun:  one cell (one object, one learner, all seeds) again, with and without XLA's
#         deterministic options, for the bit-for-bit check and the options' cost.
# A run directory under $RUNS resumes after its last finished round (unpack an earlier
# runs.tgz there first). Every job's host and seconds go to $OUT/jobs.txt, its log to
# $RUNS/<job>.log; at the end the logs and run directories are packed into $OUT/runs.tgz.
set -uo pipefail
: "${OUT:?}" "${RUNS:?}" "${STAGE:?}"
mkdir -p "$OUT" "$RUNS"
export XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1
NCPU=$(nproc); NGPU=$(nvidia-smi -L 2>/dev/null | wc -l); [ "$NGPU" -ge 1 ] || NGPU=1
BENCH=${BENCH:-sern_jax/grasp/data/benchmarks/wedges.json}
{ echo "stage $STAGE utc_start $(date -u +%FT%TZ)"; uptime; echo "cpus $NCPU"
  lscpu | grep -E "^Model name"; nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
  python3 -c "import jax, sys; print('python', sys.version.split()[0], 'jax', jax.__version__)"
} >> "$OUT/jobs.txt" 2>&1

job() {  # job NAME CORES GPU CMD...: one command on cores CORES and GPU GPU, timed, logged
  local name=$1 cores=$2 gpu=$3; shift 3
  local t0; t0=$(date +%s)
  CUDA_VISIBLE_DEVICES=$gpu taskset -c "$cores" "$@" > "$RUNS/$name.log" 2>&1
  local rc=$?
  echo "$name cores=$cores gpu=$gpu rc=$rc seconds=$(( $(date +%s) - t0 )) :: $*" >> "$OUT/jobs.txt"
}

share() {  # share I N: the core range of share I of N equal shares
  local per=$(( NCPU / $2 )); echo "$(( $1 * per ))-$(( ($1 + 1) * per - 1 ))"
}

case "$STAGE" in
screen)
  job select "0-$((NCPU - 1))" 0 python3 -m sern_jax.commands.main grasp screen \
    $(python3 -c "from sern_jax.grasp.world import objects; print(' '.join(objects.wedge_names()))") \
    --poses 8 --trials 8 --seed 0 --json-out "$OUT/select.json" --no-progress
  CANDIDATES=$(python3 -m experiments.benchmark_objects candidates --select "$OUT/select.json")
  job confirm "0-$((NCPU - 1))" 0 python3 -m sern_jax.commands.main grasp screen $CANDIDATES \
    --poses 8 --trials 16 --seed 1 --json-out "$OUT/confirm.json" --no-progress
  job objects 0 0 python3 -m experiments.benchmark_objects write --select "$OUT/select.json" \
    --confirm "$OUT/confirm.json" --name wedges --out "$RUNS/wedges.json"
  [ -f "$RUNS/wedges.json" ] || exit 1
  SCORED=$(python3 -c "import json; print(','.join(o['name'] for o in json.load(open('$RUNS/wedges.json'))['objects']))")
  job checks "0-$((NCPU - 1))" 0 python3 -m experiments.trial_checks --objects "$SCORED" \
    --poses 8 --candidates 16 --steps 2 --forces "" --mjx --out "$OUT/trial_checks.json"
  ;;
tune)
  for i in 0 1 2 3 4; do
    job "tune$i" "$(share $i 5)" $((i % NGPU)) python3 -m experiments.benchmark_tune run \
      --benchmark "$BENCH" --setting $i --out "$RUNS/tune" --no-progress &
  done
  wait
  for ext in 1 2; do
    python3 -m experiments.benchmark_tune choose --out "$RUNS/tune" --record "$RUNS/tuning" \
      > "$RUNS/choose$ext.log" 2>&1
    VALUES=$(python3 -c "
import json
d = json.load(open('$RUNS/tuning/tuned.json'))['learners']
print(','.join(f'{n}={v[\"next_value\"]}' for n, v in d.items() if v['next_value'] is not None))")
    [ -n "$VALUES" ] || break
    job "extend$ext" "0-$((NCPU - 1))" 0 python3 -m experiments.benchmark_tune run \
      --benchmark "$BENCH" --values "$VALUES" --out "$RUNS/tune" --no-progress
  done
  python3 -m experiments.benchmark_tune choose --out "$RUNS/tune" --record "$OUT" \
    > "$RUNS/choose.log" 2>&1
  ;;
run)
  : "${OBJECTS:?}"
  PARALLEL=${PARALLEL:-4}; i=0
  for obj in $OBJECTS; do
    job "part_$obj" "$(share $((i % PARALLEL)) "$PARALLEL")" $((i % NGPU)) \
      python3 -m sern_jax.commands.main grasp learn --benchmark "$BENCH" "$obj" \
      --out "$RUNS/$obj" --no-figures --no-progress &
    i=$((i + 1))
    if (( i % PARALLEL == 0 )); then wait; fi
  done
  wait
  ;;
rerun)
  : "${OBJECT:?}" "${LEARNER:?}"
  job "rerun_$OBJECT" "0-$((NCPU - 1))" 0 python3 -m sern_jax.commands.main grasp learn \
    --benchmark "$BENCH" "$OBJECT" --policies "$LEARNER" --out "$RUNS/rerun_$OBJECT" \
    --no-figures --no-progress
  job "rerun_nondet_$OBJECT" "0-$((NCPU - 1))" 0 env SERN_GPU_NONDETERMINISTIC=1 python3 -m \
    sern_jax.commands.main grasp learn --benchmark "$BENCH" "$OBJECT" --policies "$LEARNER" \
    --out "$RUNS/rerun_nondet_$OBJECT" --no-figures --no-progress
  ;;
*) echo "STAGE must be screen, tune, run or rerun" >&2; exit 2 ;;
esac
echo "stage $STAGE utc_end $(date -u +%FT%TZ)" >> "$OUT/jobs.txt"
tar czf "$OUT/runs.tgz" --exclude='.jax_cache' -C "$RUNS" .
