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


@pytest.mark.parametrize("argv, needle", [
    (["--dataset-objects", "-1"], "--dataset-objects"),
    (["--dataset-objects", "2", "--dataset-poses", "0"], "--dataset-poses"),
    (["--dataset-objects", "2", "--dataset-backends", "native,gpu"], "--dataset-backends"),
    (["--dataset-backends", "mjx,mjx"], "--dataset-backends"),
    (["--mjx-reference"], "--mjx-reference"),  # times the --objects batch: needs --objects
])
def test_bad_dataset_flags_are_refused_before_any_work(argv, needle):
    from sern_jax.commands import bench_grasp

    with pytest.raises(ValueError, match=needle) as info:
        bench_grasp.main(["grasp", *argv])
    assert "\n" not in str(info.value)


def test_dataset_rates_split_first_shard_and_project():
    """MJX: 3 shards of 10 objects, the first with the compile; the steady shard is the
    mean of the others, the projection the first shard plus 19 steady ones (200 objects)."""
    from sern_jax.bench import grasp as bench

    shard = {"objects": 10, "trials": 6_000, "contexts_s": 4.0, "trials_s": 2.0,
             "waited_s": 0.0, "compiled": 0}
    stats = [{**shard, "trials_s": 62.0, "seconds": 66.0, "compiled": 1},
             {**shard, "seconds": 4.0}, {**shard, "seconds": 4.0}]
    row = bench.dataset_rates("mjx", stats, 74.0, objects_per_shard=10)
    assert row["trials"] == 18_000 and row["mjx_compiles"] == 1
    assert row["first_shard_s"] == 66.0 and row["rest_s"] == 8.0
    assert row["compile_s"] == 60.0 and row["bound"] == "host contexts"
    d0 = row["projections"]["d0_default"]
    assert d0["objects"] == 200 and d0["seconds"] == 66.0 + 19 * 4.0
    assert d0["grasps"] == 200 * 600
    assert row["projections"]["dexnet_objects"]["seconds"] == 66.0 + 399 * 4.0
    assert row["projections"]["dexnet_grasps"]["objects"] == bench.DEXNET_GRASPS // 600 + 1
    native = bench.dataset_rates("native", [{**shard, "seconds": 6.0}] * 2, 12.0, 10)
    assert native["projections"]["d0_default"]["seconds"] == 120.0
    assert native["bound"] == "host contexts"
