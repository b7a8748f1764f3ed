#!/bin/bash
# The strong setting as one command (20 seeds), timed: uptime before/after, `/usr/bin/time -v`,
# the exact command, then the cell-by-cell comparison with the committed one-command run
# experiments/results/strong/single_command_h100/strong.json. Usage, from the repository root
# (OUT an output folder): OUT=/tmp/out bash experiments/diagnostics/strong_single_command.sh
# Records made with it: experiments/results/strong/single_command_h100_*/.
set -o pipefail
R=$OUT/strong_single; mkdir -p $R
{ echo "utc_start $(date -u +%FT%TZ)"; echo "uptime_before $(uptime)"; nproc; lscpu | grep -E "^(CPU\(s\)|Model name|Thread)"; nvidia-smi --query-gpu=name,memory.total --format=csv,noheader; git rev-parse HEAD 2>/dev/null; git status --short 2>/dev/null | head -40; } > $R/context.txt 2>&1
t0=$(date +%s.%N)
/usr/bin/time -v -o $R/time_v.txt python3 -m experiments.grasp_learning strong --seeds 20 --no-progress --out /tmp/runs/strong --results $R 2>&1 | grep -v "Warning\|warn(" | tee $R/log.txt
rc=$?
t1=$(date +%s.%N)
{ echo "uptime_after $(uptime)"; echo "utc_end $(date -u +%FT%TZ)"; echo "wall $(python3 -c "print($t1 - $t0)") rc $rc"; } >> $R/context.txt
cat $R/context.txt | tail -3
python3 - <<'PY'
import json, os, numpy as np
new = json.load(open(os.environ["OUT"] + "/strong_single/strong.json"))
old = json.load(open("experiments/results/strong/single_command_h100/strong.json"))
for f in ("lowvar_eval", "paper_eval", "explore_success"):
    a, b = np.array(new[f]), np.array(old[f])
    print(f, "shape", a.shape, "cells differing from the committed one-command run:", int((a != b).sum()), "of", a.size, "| per round:", [int((a[r] != b[r]).sum()) for r in range(a.shape[0])])
print("trial_counts new", new.get("trial_counts"), "old", old.get("trial_counts"))
print("timings new", new.get("timings"))
PY
