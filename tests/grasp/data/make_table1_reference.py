"""Writes tests/grasp/data/table1_reference.json: the Table I that the slow test
``test_paper_setting_table_unchanged`` (tests/grasp/test_runner.py) compares
``sern grasp learn``'s defaults with, bit for bit.

The first copy was written by the pre-refactor ``online.run`` (commit 2b20d9d) with the 6 N
θ0. The trial and θ0 changed on 2026-11-24 (20 N fingers, Newton 20 / 20, a new θ0 and
hard set: docs/GRASP.md), so the reference was re-derived with this script from the runner
of that day, on the shared 2-core CPU machine (XLA on another machine or a GPU may move
near-ties, docs/LEARNING.md). Run from the repository root (about 5 min on 2 idle cores):

    python tests/grasp/data/make_table1_reference.py
"""

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.world import objects
from sern_jax.grasp.online import config as online_config  # noqa: E402
from sern_jax.grasp.online import driver  # noqa: E402


def main() -> None:
    t = time.perf_counter()
    theta0 = artifacts.load_theta0()
    specs = [objects.make_object(n) for n in artifacts.hard_set(theta0)["objects"]]
    with tempfile.TemporaryDirectory() as out:
        res = driver.run(online_config.OnlineConfig(), specs, out, theta0=theta0,
                         progress=False, log=lambda *_: None)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    ref = {
        "command": "python tests/grasp/data/make_table1_reference.py (driver.run with "
                   "OnlineConfig() on artifacts.hard_set: the defaults of sern grasp learn)",
        "commit": f"{commit} (the runner and the 20 N theta0 of 2026-11-24)",
        "machine": f"{platform.platform()}, {os.cpu_count()} CPUs, load average "
                   f"{os.getloadavg()[0]:.1f}; {time.perf_counter() - t:.0f} s",
        "trial_counts": res["trial_counts"],
        "table": [{k: v for k, v in r.items() if k not in ("sd", "se")} for r in res["table"]],
    }
    path = Path(__file__).with_name("table1_reference.json")
    path.write_text(json.dumps(ref, indent=1) + "\n")
    print(f"wrote {path}: {ref['machine']}")


if __name__ == "__main__":
    main()
