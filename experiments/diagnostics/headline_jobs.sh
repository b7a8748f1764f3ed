#!/bin/bash
# The grasp-learning headline runs on one many-core GPU host (16 cores, one GPU), several at
# once, each pinned to its own cores and stopped at its own time limit; what finished (or, for
# a stopped run, the rounds it finished: `collect`) goes into one archive, $OUT/results.tgz,
# with every job's log. Usage, from the repository root (OUT an output folder):
#
#     OUT=/tmp/out bash experiments/diagnostics/headline_jobs.sh JOB [JOB ...]
#
# where a JOB is NAME:CORES:LIMIT_S, NAME one of
#   strong1 strong2 strong3   the 20-seed strong run, objects 1-2, 3-4, 5-6 of the hard set
#   transfer-<cell>           one 20-round transfer cell (experiments.grasp_sensitivity;
#                             5 seeds, the first TR_OBJECTS=3 objects of the hard set)
#   sens-<cell>               one cell of the sensitivity grid under the 20 N trial, e.g.
#                             sens-10N_mu0.2-0.5_d435 (experiments.grasp_sensitivity cell;
#                             SENS_SEEDS=10 seeds, 5 rounds, the 6 objects of the hard set)
#   abl1 abl2 abl3 abl4       the ablations' distinct runs, in four parts
#   paper alpha core_set loss schedule regret   a grasp_learning setting
# e.g. strong1:0-3:560 transfer-A:12-13:560. The results' per-seed files name the command,
# the machine and the seconds; this script only schedules them. (SMOKE="--objects 1 --seeds
# 2 --rounds 1" shrinks every run, for trying the script itself.) Records made with it:
# experiments/results/{strong,alpha,transfer,sensitivity}/ (their jobs files).
set -u
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
T0=$(date +%s)
R=$OUT/res
mkdir -p "$R/logs"
# RESUME=DIR: the unpacked results.tgz of an earlier run (its checkpoints let stopped runs
# go on from their last finished round)
if [ -n "${RESUME:-}" ]; then cp -r "$RESUME"/. "$R"/; fi
RUNS=${RUNS:-$R/runs}
HARD=($(python3 -c "from sern_jax.grasp.model import artifacts as a; print(' '.join(a.hard_set(a.load_theta0(), 6)['objects']))"))
echo "hard set: ${HARD[*]}" | tee "$R/logs/jobs.txt"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader >> "$R/logs/jobs.txt" 2>&1
lscpu | grep -E "Model name|^CPU\(s\)" >> "$R/logs/jobs.txt"

# every 10 s: each run's checkpointed next round (how far a stopped run got, and when)
(
  while sleep 10; do
    for c in "$R"/*/runs/*/checkpoint.npz "$RUNS"/*/checkpoint.npz; do
      [ -f "$c" ] && echo "$(( $(date +%s) - T0 )) s $c next_round $(python3 -c \
        "import numpy as np,sys; print(int(np.load(sys.argv[1])['next_round']))" "$c" 2>&1)"
    done
  done
) >> "$R/logs/progress.txt" 2>&1 &
WATCH=$!

run() {  # NAME CORES LIMIT CMD...
  local name=$1 cores=$2 limit=$3
  shift 3
  (
    s=$(date +%s)
    timeout -s KILL "$limit" taskset -c "$cores" "$@" > "$R/logs/$name.log" 2>&1
    echo "$name: exit $? after $(( $(date +%s) - s )) s on cores $cores: $*" >> "$R/logs/jobs.txt"
  ) &
  PIDS+=($!)
}
PIDS=()

for job in "$@"; do
  IFS=: read -r name cores limit <<< "$job"
  case $name in
    strong1) run "$name" "$cores" "$limit" python3 -m experiments.grasp_learning strong \
               --seeds 20 --only "${HARD[0]},${HARD[1]}" --no-progress --out $RUNS/strong \
               --results "$R/strong" ${SMOKE:-} ;;
    strong2) run "$name" "$cores" "$limit" python3 -m experiments.grasp_learning strong \
               --seeds 20 --only "${HARD[2]},${HARD[3]}" --no-progress --out $RUNS/strong \
               --results "$R/strong" ;;
    strong3) run "$name" "$cores" "$limit" python3 -m experiments.grasp_learning strong \
               --seeds 20 --only "${HARD[4]},${HARD[5]}" --no-progress --out $RUNS/strong \
               --results "$R/strong" ;;
    transfer-*) run "$name" "$cores" "$limit" python3 -m experiments.grasp_sensitivity \
               transfer-cell "${name#transfer-}" --out "$R/transfer" --seeds 5 --rounds 20 \
               --objects ${TR_OBJECTS:-3} ${SMOKE:-} ;;
    sens-*) run "$name" "$cores" "$limit" python3 -m experiments.grasp_sensitivity \
               cell "${name#sens-}" --out "$R/sensitivity" --seeds ${SENS_SEEDS:-10} \
               --rounds 5 --objects 6 ${SMOKE:-} ;;
    abl1|abl2|abl3|abl4) labels=(x "alpha=0.01,alpha=0.05" "alpha=0.2,alpha=1.0"
               "core=none,core=random" "loss=l1,schedule")
             run "$name" "$cores" "$limit" python3 -m experiments.grasp_learning ablations \
               --labels "${labels[${name#abl}]}" --no-progress --out "$RUNS/ablations" \
               --results "$R" ${SMOKE:-} ;;
    paper|alpha|core_set|loss|schedule|regret) run "$name" "$cores" "$limit" python3 -m \
               experiments.grasp_learning "$name" --no-progress --out "$RUNS/$name" \
               --results "$R/$name" ${SMOKE:-} ;;
    *) echo "unknown job $name" >> "$R/logs/jobs.txt" ;;
  esac
done
wait "${PIDS[@]}"
kill "$WATCH" 2>/dev/null
# stopped runs: their finished rounds, from the checkpoints
for s in transfer sensitivity; do
  [ -d "$R/$s/runs" ] && python3 -m experiments.grasp_learning collect "$R/$s/runs" "$R/$s" \
    >> "$R/logs/collect.log" 2>&1
done
for d in "$RUNS"/*; do
  dest="$R/$(basename "$d")"
  [ "$(basename "$d")" = ablations ] && dest="$R"
  [ -d "$d" ] && python3 -m experiments.grasp_learning collect "$d" "$dest" \
    >> "$R/logs/collect.log" 2>&1
done
echo "all jobs done after $(( $(date +%s) - T0 )) s" >> "$R/logs/jobs.txt"
cd "$R" && tar czf "$OUT/results.tgz" . && cp logs/jobs.txt "$OUT/" && du -sh "$OUT/results.tgz"
cat "$R/logs/jobs.txt"
