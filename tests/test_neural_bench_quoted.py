"""The benchmark figures docs/NEURAL.md quotes are those of the committed JSON files of
``sern bench neural --json`` (experiments/results/bench/neural_wheel_lints_*.json)."""

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "experiments" / "results" / "bench"


def _load(name):
    return json.loads((BENCH / name).read_text())


def test_quoted_benchmark_figures_match_the_files():
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    t5000 = _load("neural_wheel_lints_2core_T5000.json")
    t500 = _load("neural_wheel_lints_2core_T500.json")
    h100 = _load("neural_wheel_lints_h100_T500.json")
    idle = _load("neural_wheel_lints_2core_T5000_idle.json")
    assert t5000["workload"]["num_seeds"] == 1000 and t5000["workload"]["horizon"] == 5000
    assert h100["workload"]["num_seeds"] == 100_000 and h100["machine"]["backend"] == "gpu"
    b = t5000["batched"]
    quoted = [f"{b['seed_rounds_per_s']:,.0f} seed-rounds/s: {b['seconds']:.1f} s wall, "
              f"{b['cpu_seconds']:.0f} CPU-s",
              f"{t5000['python_loop']['seed_rounds_per_s']:.0f} seed-rounds/s",
              f"{t5000['speedup']:.0f}×",
              f"{t500['batched']['seed_rounds_per_s']:,.0f} seed-rounds/s: "
              f"{t500['batched']['seconds']:.1f} s wall",
              f"{h100['batched']['seed_rounds_per_s']:,.0f} seed-rounds/s "
              f"({h100['batched']['seconds']:.2f} s)",
              f"{h100['batched_compile_s']:.1f} s",
              f"{h100['batched']['seed_rounds_per_s'] / t500['batched']['seed_rounds_per_s']:.0f}× "
              f"the 2-core figure"]
    # the idle 2-core run (the lead's, abfbe19): JSON and the raw time -v output beside it
    assert idle["workload"]["num_seeds"] == 1000 and idle["workload"]["horizon"] == 5000
    assert idle["machine"]["cores_usable"] == 2 and idle["machine"]["load_average_1min"] < 2
    raw = (BENCH / "neural_wheel_lints_2core_T5000_idle.txt").read_text()
    assert json.loads(raw.splitlines()[2]) == idle
    assert "Elapsed (wall clock) time (h:mm:ss or m:ss): 3:15.19" in raw
    assert "Maximum resident set size (kbytes): 1597468" in raw
    ib = idle["batched"]
    quoted += [f"{ib['seed_rounds_per_s']:,.0f} seed-rounds/s: {ib['seconds']:.1f} s wall",
               f"{ib['cpu_seconds']:.0f} CPU-s (compile {idle['batched_compile_s']:.1f} s apart)",
               f"Python loop's {idle['python_loop']['seed_rounds_per_s']:.0f} seed-rounds/s "
               f"in the same process ({idle['speedup']:.0f}×)",
               f"load average {idle['machine']['load_average_1min']:.1f} at the start, "
               f"{idle['load_average_end'][0]:.1f} at the end",
               f"{h100['batched']['seed_rounds_per_s'] / ib['seed_rounds_per_s']:.0f}× the idle "
               f"2-core figure",
               "3 min 15 s wall", "peak RSS 1.6 GB"]
    for q in quoted:
        assert q in doc, q


def test_pooled_default_idle_figures_match_the_files():
    """docs/NEURAL.md's re-measurement under the pooled-σ² default (the lead's run, 1bdc7ed)."""
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    old = _load("neural_wheel_lints_2core_T5000_idle.json")
    new = _load("neural_wheel_lints_2core_T5000_idle_pooled.json")
    raw = (BENCH / "neural_wheel_lints_2core_T5000_idle_pooled.txt").read_text()
    assert json.loads(raw.splitlines()[2]) == new and raw.splitlines()[0] == "1bdc7ed"
    assert new["workload"] == old["workload"] and new["machine"]["cores_usable"] == 2
    assert "Elapsed (wall clock) time (h:mm:ss or m:ss): 3:41.09" in raw
    b = new["batched"]
    for q in (f"{b['seed_rounds_per_s']:,.0f} seed-rounds/s, {b['seconds']:.1f} s wall",
              f"{b['cpu_seconds']:.0f} CPU-s (compile {new['batched_compile_s']:.1f} s apart)",
              f"Python loop {new['python_loop']['seed_rounds_per_s']:.0f} seed-rounds/s "
              f"({new['speedup']:.0f}×)",
              f"load average was {new['machine']['load_average_1min']:.1f} at the start",
              f"{new['load_average_end'][0]:.1f} at the end",
              f"mean regret at T {b['regret_rb_T_mean']:,.0f} against the per-arm learner's "
              f"{old['batched']['regret_rb_T_mean']:,.0f}",
              f"{100 * (b['seconds'] / old['batched']['seconds'] - 1):.0f} % "
              f"({b['seconds']:.1f} s against {old['batched']['seconds']:.1f} s)",
              "the whole command 3 min 41 s"):
        assert q in doc, q
