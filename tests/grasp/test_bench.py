"""``sern bench grasp``: stdout under --json is exactly one JSON object; bad sizes fail early."""

import json
import subprocess
import sys

import pytest


def _bench(*argv):
    return subprocess.run(
        [sys.executable, "-m", "sern_jax.commands.main", "bench", "grasp", *argv],
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_json_stdout_is_one_object():
    # A fresh process: mujoco.mjx prints its "Failed to import warp" notice on first import,
    # which must go to stderr (the depth stage imports mjx).
    proc = _bench(
        "--json", "--native-batch", "4", "--mjx-batch", "", "--depth-batch", "1",
        "--repeats", "1",
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 1, proc.stdout
    out = json.loads(lines[0])
    native = out["backends"]["native"]["batches"][0]
    assert native["batch"] == 4 and native["trials_per_s"] > 0 and native["nan"] == 0
    assert out["depth"]["batch"] == 1 and out["depth"]["images_per_s"] > 0
    assert out["candidates"]["num_candidates"] == 64
    assert "mjx" not in out["backends"]
    qn = out["quality_net"]
    assert qn["train_steps_per_s"] > 0 and qn["sets_scored_per_s"] > 0
    for field in ("cpu", "cpu_count", "platform", "processor", "python", "jax_backend",
                  "jax_devices", "load_average_1m"):  # io.machine(devices=True)
        assert field in out["machine"], field
    assert native["first_call_s"] > 0 and native["seconds"] > 0
    assert native["trials_per_cpu_s"] > 0


@pytest.mark.parametrize(
    "argv, needle",
    [(["--native-batch", "4,x"], "--native-batch"), (["--repeats", "0"], "--repeats")],
)
def test_bad_sizes_exit_2_naming_the_flag(argv, needle):
    proc = _bench("--json", "--mjx-batch", "", *argv)
    assert proc.returncode == 2
    assert needle in proc.stderr and proc.stdout == ""
