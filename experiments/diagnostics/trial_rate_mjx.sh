#!/bin/bash
# Native-MJX agreement and trial rates under the 20 N trial, on one GPU host (16 cores, one
# GPU). Usage, from the repository root (OUT an output folder):
#     OUT=/tmp/out bash experiments/diagnostics/trial_rate_mjx.sh
# 1. the native rate pinned to 2 cores (taskset -c 0,1, --threads 2; the 2-core CPU's
#    command) and, at the same time on the other 14 cores, the MJX rate on the GPU at batch
#    32,768 (against a target of >= 5,000 trials/s); 2. the paired native/MJX agreement, one
#    process per object (48 trials each; seeds as `sern bench grasp --agreement 48
#    --agreement-objects OBJ` gives them, i.e. object index 0), on cores 2-15 and the GPU.
# Everything goes into $OUT/results.tgz with every command's log and jobs.txt (machine,
# versions, commit, seconds per step). Records: experiments/results/trial_rate/ and
# experiments/results/agreement/.
set -u
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
R=$OUT/res
mkdir -p "$R"
T0=$(date +%s)
note() { echo "[$(( $(date +%s) - T0 )) s] $*" >> "$R/jobs.txt"; }
{
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
  lscpu | grep -E "Model name|^CPU\(s\)"
  python3 -c "import jax, mujoco, mujoco.mjx, sys; print('python', sys.version.split()[0], 'jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())"
  git log -1 --format='commit %H' 2>/dev/null || echo "commit: no git here"
  uptime
} >> "$R/jobs.txt" 2>&1
BENCH="python3 -m sern_jax.commands.main bench grasp --json --depth-batch 0 --context-poses '' --quality-sets 0"
step() {  # NAME CORES LIMIT ARGS...: one sern bench grasp call, pinned, time-limited
  local name=$1 cores=$2 limit=$3
  shift 3
  local s=$(date +%s)
  timeout -s KILL "$limit" taskset -c "$cores" \
    python3 -m sern_jax.commands.main bench grasp --json --depth-batch 0 --context-poses '' \
    --quality-sets 0 "$@" --out "$R/$name.json" > "$R/$name.log" 2>&1
  note "$name: exit $? after $(( $(date +%s) - s )) s, taskset -c $cores: sern bench grasp --json --depth-batch 0 --context-poses '' --quality-sets 0 $* --out $name.json"
}
note "step 1: native 2-core rate (cores 0-1) beside the MJX GPU rate (cores 2-15)"
step rate_native_2core 0,1 90 --native-batch 64,256,1024 --mjx-batch '' --threads 2 --repeats 3 &
step rate_mjx_gpu 2-15 120 --native-batch 64 --threads 14 --mjx-batch 32768 --repeats 2 &
wait
note "step 2: agreement, one process per object, cores 2-15 + GPU"
for o in ${AGREE_OBJECTS:-small_box l_shape triangular_prism pipe_tee tless_part_a handle_jug detergent_bottle pipe_tee_steel}; do
  step "agreement_$o" 2-15 ${AGREE_LIMIT:-150} --native-batch 64 --mjx-batch '' --repeats 1 \
    --agreement ${AGREE_TRIALS:-48} --agreement-objects "$o" &
done
wait
uptime >> "$R/jobs.txt"
note "done"
tar czf "$OUT/results.tgz" -C "$R" .
cat "$R/jobs.txt"
