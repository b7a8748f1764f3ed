"""Where the strong setting's wall time goes, as a timeline.

Runs ``python -m experiments.grasp_learning strong --seeds 20 --no-progress`` in this process
with the grasp runner's pieces wrapped (scheduling is untouched: each wrapper only records
when its call started and ended, in which thread) and JAX's compile events recorded, then
writes ``$OUT/timeline/events.json`` and prints a summary: for each kind of work, its calls,
their total and their span on the clock; compiles by thread; when each round's checkpoint was
written. Nothing in the package imports it.

Written against the grasp runner of commit cbeac03. Run from the repository root (``OUT`` an
output folder):
    OUT=/tmp/out python3 experiments/diagnostics/strong_timeline.py
Record: experiments/results/strong/timeline/timeline_h100.txt.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

T0 = time.perf_counter()
EVENTS: list = []
LOCK = threading.Lock()


def record(kind, start, end, **info):
    with LOCK:
        EVENTS.append({"kind": kind, "start": start - T0, "end": end - T0,
                       "thread": threading.current_thread().name, **info})


def wrap(module, name, kind, block=False, info=None):
    real = getattr(module, name)

    def timed(*args, **kwargs):
        t = time.perf_counter()
        out = real(*args, **kwargs)
        if block:
            import jax
            jax.block_until_ready(out)
        record(kind, t, time.perf_counter(), **(info(*args, **kwargs) if info else {}))
        return out

    setattr(module, name, timed)


def main():
    import jax
    import jax.monitoring

    def on_duration(event, duration, **kw):
        if "compile" in event:
            end = time.perf_counter()
            record("jax:" + event.rsplit("/", 1)[-1], end - duration, end)

    jax.monitoring.register_event_duration_secs_listener(on_duration)

    from sern_jax.grasp.world import context
    from sern_jax.grasp.online import checkpoint, driver, step

    wrap(driver, "contexts_of_stream", "context_batch",
         info=lambda key, stream, r, spec, num, *a: {"stream": int(stream), "round": int(r),
                                                     "num": int(num), "object": spec.name})
    wrap(context, "_resting_poses", "resting_poses")
    real_pipeline = context._pipeline

    def pipeline(*args):
        fn = real_pipeline(*args)

        def timed(*a):
            t = time.perf_counter()
            out = jax.block_until_ready(fn(*a))
            record("render_sample", t, time.perf_counter(), num=int(a[1].geom_xpos.shape[0]))
            return out
        return timed

    context._pipeline = pipeline
    wrap(step, "run_trials", "trials",
         info=lambda sims, grasps, *a, **k: {"requested": int(grasps.size // 4)})
    wrap(step, "stack_contexts", "stack_contexts")
    wrap(checkpoint, "save", "save", info=lambda path, fp, res, rew, nr: {"next_round": int(nr)})

    from experiments import grasp_learning
    out = Path(os.environ.get("OUT", "/tmp")) / "timeline"
    out.mkdir(parents=True, exist_ok=True)
    rc = grasp_learning.main(["strong", "--seeds", "20", "--no-progress", "--out",
                              "/tmp/runs/strong_timeline", "--results", str(out / "results")])
    total = time.perf_counter() - T0
    (out / "events.json").write_text(json.dumps({"total_s": total, "events": EVENTS}))
    summarise(EVENTS, total)
    return rc


def summarise(events, total):
    print(f"total {total:.1f} s (from the script's start, imports included)")
    by = defaultdict(list)
    for e in events:
        by[e["kind"]].append(e)
    for kind, es in sorted(by.items()):
        dur = sum(e["end"] - e["start"] for e in es)
        print(f"{kind:22s} calls {len(es):5d}  sum {dur:8.1f} s  span {min(e['start'] for e in es):6.1f}"
              f" .. {max(e['end'] for e in es):6.1f} s")
    for e in by["save"]:
        print(f"checkpoint next_round {e['next_round']} at {e['end']:.1f} s")
    for e in by["trials"]:
        print(f"trials {e['requested']:6d} requested in {e['thread']:20s} "
              f"{e['start']:6.1f} .. {e['end']:6.1f} s")
    batches = defaultdict(list)
    for e in by["context_batch"]:
        batches[(e["stream"], e["round"], e["num"])].append(e)
    for (stream, r, num), es in sorted(batches.items(), key=lambda kv: min(e["start"] for e in kv[1])):
        print(f"contexts stream {stream} round {r} P={num}: {len(es)} batches, "
              f"{min(e['start'] for e in es):6.1f} .. {max(e['end'] for e in es):6.1f} s, "
              f"sum {sum(e['end'] - e['start'] for e in es):6.1f} s")
    compiles = defaultdict(float)
    for kind, es in by.items():
        if kind.startswith("jax:"):
            for e in es:
                compiles[e["thread"].split("_")[0]] += e["end"] - e["start"]
    print("compile seconds by thread family:", {k: round(v, 1) for k, v in compiles.items()})


if __name__ == "__main__":
    sys.exit(main())
