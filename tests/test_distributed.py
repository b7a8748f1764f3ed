"""Ray scale-out (sern_jax.infra.distributed): a Ray run writes the same files as the
single-process run, resumes, retries killed workers, and stops on a failing unit in one line.

The default run uses one local Ray with 2 CPUs for the whole module (started once, ~4 s).
The ``slow`` test starts a real two-node cluster on loopback (``ray start``), kills a worker
process mid-run, and compares with the single-process results.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sern_jax.infra import distributed, io
from sern_jax.commands.main import main

ROOT = Path(__file__).resolve().parents[1]
TINY = ["regret", "--policies", "softmax,greedy", "-T", "300", "-S", "48", "--chunk-size",
        "16", "--no-figures", "--no-progress"]


# ----------------------------------------------------------------------- without ray


def test_importing_and_running_without_ray_never_imports_ray(tmp_path):
    code = (
        "import sys\n"
        "import sern_jax, sern_jax.infra.distributed, sern_jax.infra.io\n"
        "from sern_jax.commands.main import main\n"
        f"assert main({TINY + ['-S', '8', '--out', str(tmp_path / 'r')]!r}) == 0\n"
        "assert 'ray' not in sys.modules, 'ray was imported'\n"
        "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("ok")


def test_ray_missing_is_one_line_naming_the_flag_and_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    out = tmp_path / "r"
    assert main(TINY + ["--ray", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "--ray" in err and ".[ray]" in err
    assert not out.exists()


def _status(argv) -> int:
    """``main``'s exit status, whether it returns it or argparse exits with it (a flag's
    typed parser refuses a bad value while parsing)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize("flags, named", [
    (["--ray-workers", "2"], "--ray-workers"),  # a companion without --ray
    (["--ray-gpus", "1"], "--ray-gpus"),
    (["--ray", "--ray-workers", "0"], "--ray-workers"),
    (["--ray", "--ray-cpus", "0"], "--ray-cpus"),
    (["--ray", "--ray-gpus", "-1"], "--ray-gpus"),
    (["--ray", "--ray-retries", "-1"], "--ray-retries"),
    (["--ray", "auto", "--ray-workers", "2"], "--ray-workers"),
    (["--ray", "--devices", "2"], "--devices"),
])
def test_bad_ray_flags_are_one_line(tmp_path, capsys, flags, named):
    out = tmp_path / "r"
    assert _status(TINY + flags + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err, err
    assert not out.exists()


def test_baselines_ray_refusals_are_one_line(tmp_path, capsys):
    """`experiments.grasp_baselines` refuses bad Ray flags in one line (not argparse's
    usage block), exit 2, nothing written."""
    import experiments.grasp_baselines as grid

    for flags, named in ((["run", "--ray", "--ray-workers", "0"], "--ray-workers"),
                         (["collect", "--ray"], "--ray applies to tune"),
                         (["run", "--ray-gpus", "1"], "--ray-gpus")):
        with pytest.raises(SystemExit) as exc:
            grid.main(flags + ["--out", str(tmp_path / "o")])
        err = capsys.readouterr().err.strip()
        assert exc.value.code == 2 and len(err.splitlines()) == 1 and named in err, err
    assert not (tmp_path / "o").exists()


def test_mjx_on_ray_without_gpus_is_refused_in_one_line(tmp_path, capsys):
    """MJX tasks on the CPU would be another float program than a GPU run of the same run
    directory (the fingerprint does not name the platform): `--ray-gpus` is required."""
    pytest.importorskip("ray")
    import experiments.grasp_baselines as grid

    out = tmp_path / "r"
    for argv in (LEARN, ["grasp", "dataset", "--objects", "2", "--no-progress"]):
        assert main(argv + ["--backend", "mjx", "--ray", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--ray-gpus" in err and "mjx" in err, err
        assert not out.exists()
    for what in ("run", "tune"):
        with pytest.raises(SystemExit) as exc:
            grid.main([what, "--backend", "mjx", "--ray", "--out", str(out)])
        err = capsys.readouterr().err.strip()
        assert exc.value.code == 2 and len(err.splitlines()) == 1 and "--ray-gpus" in err
    assert not out.exists()
    distributed.check_backend("mjx", distributed.RayConfig(gpus_per_task=0.5))  # allowed
    distributed.check_backend("native", distributed.RayConfig())
    with pytest.raises(ValueError, match="--ray-gpus"):
        distributed.check_backend("mjx", distributed.RayConfig())


def test_baselines_run_refuses_another_runs_directory_before_writing_meta(tmp_path, capsys,
                                                                        monkeypatch):
    """A run directory whose checkpoint has another fingerprint: refused in one line, exit
    2, before meta.json is rewritten with the new settings (it was, before the refusal)."""
    import experiments.grasp_baselines as grid

    (tmp_path / "run").mkdir()
    io.save_npz(tmp_path / "run" / "checkpoint.npz", fingerprint=np.str_("0123456789abcdef"),
                next_round=np.int64(1))
    meta = json.dumps({"num_seeds": 99, "calls": [{"start_round": 0}]})
    (tmp_path / "meta.json").write_text(meta)
    with pytest.raises(SystemExit) as exc:
        grid.main(["run", "--out", str(tmp_path), "--untuned", "--objects", "1", "--seeds",
                   "2", "--rounds", "1", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert "holds a different learning run" in err
    assert (tmp_path / "meta.json").read_text() == meta
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meta.json", "run"]

    # the same run's checkpoint (the fingerprint the runner computes) is resumed, not refused
    from sern_jax.grasp.online import config as online_config

    specs, theta0 = grid.hard_specs()
    config = grid.online_config(grid.learners(), grid.tuned_values(tmp_path, True),
                                num_seeds=2, rounds=1, explore=20, regret_trials=0,
                                regret_grasps=0, backend="native")
    io.save_npz(tmp_path / "run" / "checkpoint.npz", next_round=np.int64(1),
                fingerprint=np.str_(online_config.run_fingerprint(config, specs[:1], theta0)))

    def reached(config, specs, run_dir, theta0, progress):
        raise RuntimeError("runner reached")

    monkeypatch.setattr(grid, "_run", reached)
    with pytest.raises(RuntimeError, match="runner reached"):
        grid.main(["run", "--out", str(tmp_path), "--untuned", "--objects", "1", "--seeds",
                   "2", "--rounds", "1", "--no-progress"])
    doc = json.loads((tmp_path / "meta.json").read_text())
    assert doc["num_seeds"] == 2 and doc["calls"][-1]["start_round"] == 1


def test_worker_env_sets_threads_cache_and_platform(tmp_path, monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2 "
                                    "intra_op_parallelism_threads=7")
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    run_dir = tmp_path / "run"
    env = distributed.worker_env(distributed.RayConfig(cpus_per_task=3), run_dir)
    assert env["SERN_CPU_THREADS"] == env["OMP_NUM_THREADS"] == "3"
    assert env["XLA_FLAGS"].split() == ["--xla_force_host_platform_device_count=2",
                                        "intra_op_parallelism_threads=3"]
    # the compilation cache is this user's, outside every run directory: resuming a run
    # directory from elsewhere never loads compiled code it holds
    cache = Path(env["JAX_COMPILATION_CACHE_DIR"])
    assert cache == tmp_path / "cache" / "sern_jax" / "jax" and cache.is_dir()
    assert cache.stat().st_mode & 0o077 == 0
    with pytest.raises(ValueError, match="inside the run directory"):
        distributed.worker_env(distributed.RayConfig(cache_dir=str(run_dir / ".jax_cache")),
                               run_dir)
    assert env["JAX_PLATFORMS"] == "cpu"
    env = distributed.worker_env(distributed.RayConfig(gpus_per_task=0.5), run_dir)
    assert "JAX_PLATFORMS" not in env and env["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"
    assert "--xla_cpu_multi_thread_eigen=false" in env["XLA_FLAGS"]


def test_executor_host_workers_honours_the_task_share(monkeypatch):
    from sern_jax.engine import drive as executor

    monkeypatch.setenv("SERN_CPU_THREADS", "3")
    assert executor.host_workers() == 3
    monkeypatch.delenv("SERN_CPU_THREADS")
    assert executor.host_workers() == len(os.sched_getaffinity(0))


def test_no_cluster_at_the_address_is_one_line(tmp_path, monkeypatch, capsys):
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("a Ray is already running in this process")

    def refuse(*args, **kwargs):
        raise ConnectionError("Could not find any running Ray instance.\nmore text")

    monkeypatch.setattr(ray, "init", refuse)
    out = tmp_path / "r"
    assert main(TINY + ["--ray", "auto", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ray auto: cannot join" in err, err
    assert not out.exists()


# ----------------------------------------------------------------------- on a local Ray

@pytest.fixture(scope="module")
def local_ray():
    """One local Ray with 2 CPUs for the module (the commands reuse an initialised Ray).
    Skips without the [ray] extra (CI installs it: .ci/run)."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    yield
    ray.shutdown()


def _error_lines(err: str) -> list[str]:
    """stderr's lines naming an error, less those Ray forwards from its workers (prefixed
    ``(<task> pid=N)``: e.g. a cancelled worker's "Fatal Python error: Aborted")."""
    return [line for line in err.splitlines()
            if "error" in line and not re.match(r"(\x1b\[\d+m)?\(\S+ pid=\d+", line)]


def _arrays(path: Path) -> dict[str, np.ndarray]:
    return io.load_npz(path)


def _assert_same_arrays(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
        assert a[k].tobytes() == b[k].tobytes(), k  # bit for bit (NaN payloads, -0.0)


def _chunk_fields(run_dir: Path) -> dict[str, dict]:
    """Each chunk file's arrays without its wall time (which no two runs share)."""
    return {p.name: {k: v for k, v in _arrays(p).items() if k != "wall_s"}
            for p in sorted((run_dir / "chunks").glob("*.npz"))}


def test_regret_on_ray_equals_single_process_and_resumes(local_ray, tmp_path, capsys,
                                                         monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    one, par = tmp_path / "one", tmp_path / "ray"
    assert main(TINY + ["--out", str(one)]) == 0
    assert main(TINY + ["--ray", "--out", str(par)]) == 0
    assert "Ray: 6 chunks" in capsys.readouterr().out
    _assert_same_arrays(_arrays(one / "results.npz"), _arrays(par / "results.npz"))
    single = _chunk_fields(one)
    assert len(single) == 6
    for name, arrays in _chunk_fields(par).items():
        _assert_same_arrays(single[name], arrays)
    assert io.load_json(one / "summary.json") == io.load_json(par / "summary.json")
    # the workers' persistent compile cache: this user's, never inside the run directory
    assert any((tmp_path / "cache" / "sern_jax" / "jax").iterdir())
    assert not (par / ".jax_cache").exists()

    # an interrupted / damaged run resumes with the same command: one chunk gone, one damaged
    chunks = sorted((par / "chunks").glob("*.npz"))
    chunks[0].unlink()
    chunks[3].write_bytes(chunks[3].read_bytes()[:100])
    (par / "results.npz").unlink()
    assert main(TINY + ["--ray", "--out", str(par)]) == 0
    out = capsys.readouterr().out
    assert "Ray: 2 chunks" in out and ": damaged (" in out and "-> recomputing" in out
    _assert_same_arrays(_arrays(one / "results.npz"), _arrays(par / "results.npz"))


def test_a_task_no_node_can_hold_is_one_line(local_ray, tmp_path, capsys):
    assert main(TINY + ["--ray", "--ray-cpus", "3", "--out", str(tmp_path / "r")]) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and "--ray-cpus 3" in err[0] and "largest has 2" in err[0], err


@pytest.mark.slow  # ~25 s on 2 shared cores: the summary runner compiles in every worker
def test_regret_summaries_on_ray_equal_single_process(local_ray, tmp_path):
    one, par = tmp_path / "one", tmp_path / "ray"
    flags = ["regret", "--policies", "softmax", "-T", "300", "-S", "32", "--chunk-size", "16",
             "--no-figures", "--no-progress", "--no-per-seed"]
    assert main(flags + ["--out", str(one)]) == 0
    assert main(flags + ["--ray", "--out", str(par)]) == 0
    _assert_same_arrays(_arrays(one / "results.npz"), _arrays(par / "results.npz"))


def test_dataset_on_ray_equals_single_process_and_resumes(local_ray, tmp_path):
    from sern_jax.grasp.model import dataset

    config = dataset.DatasetConfig(num_objects=3, poses_per_object=2, objects_per_shard=1)
    one, par = tmp_path / "one", tmp_path / "ray"
    logs: list[str] = []
    dataset.generate(config, one, progress=False, log=logs.append)
    dataset.generate(config, par, progress=False, log=logs.append,
                     ray=distributed.RayConfig())
    assert any(line.startswith("Ray: 3 shards") for line in logs), logs
    names = [p.name for p in dataset.shard_paths(one, config)]
    for name in names:
        _assert_same_arrays(_arrays(one / name), _arrays(par / name))
    assert io.load_json(one / "summary.json")["labelled_grasps"] == \
        io.load_json(par / "summary.json")["labelled_grasps"]
    # resume: a missing shard is recomputed by a task, the others are kept as they are
    kept = (par / names[0]).stat().st_mtime_ns
    (par / names[2]).unlink()
    logs.clear()
    dataset.generate(config, par, progress=False, log=logs.append,
                     ray=distributed.RayConfig())
    assert any(line.startswith("Ray: 1 shards") for line in logs), logs
    assert (par / names[0]).stat().st_mtime_ns == kept
    _assert_same_arrays(_arrays(one / names[2]), _arrays(par / names[2]))


def test_dataset_command_refuses_a_bad_ray_flag_in_one_line(tmp_path, capsys):
    out = tmp_path / "d0"
    assert _status(["grasp", "dataset", "--objects", "1", "--poses", "1", "--ray",
                    "--ray-cpus", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ray-cpus" in err
    assert not out.exists()


@pytest.mark.slow  # ~50 s on the 2 cores; the library's Ray path (the one the command calls)
# is tested in the default run: test_dataset_on_ray_equals_single_process_and_resumes
def test_dataset_command_takes_the_ray_flags(local_ray, tmp_path, capsys):
    from sern_jax.grasp.model import dataset

    out = tmp_path / "d0"
    # the command's own --ray path against the library's single-process shards; one object
    # per shard (--objects-per-shard 1) gives the default layout's arrays object by object
    assert main(["grasp", "dataset", "--objects", "2", "--poses", "1", "--ray",
                 "--objects-per-shard", "1", "--no-progress", "--out", str(out)]) == 0
    assert "Ray: 2 shards" in capsys.readouterr().out
    config = dataset.DatasetConfig(num_objects=2, poses_per_object=1)
    dataset.generate(config, tmp_path / "one", progress=False, log=lambda s: None)
    both = _arrays(tmp_path / "one" / "shard_00000.npz")  # objects 0 and 1 in one shard
    for i in range(2):
        part = _arrays(out / f"shard_{i:05d}.npz")
        rows = both["object_index"] == i
        _assert_same_arrays({k: v[rows] for k, v in both.items()}, part)


def _fake_cell(cell: str, out, seeds: int, rounds: int, objects: int) -> None:
    io.save_json(Path(out) / f"{cell}.json", {"cell": cell, "pid": os.getpid(),
                                              "seeds": seeds, "rounds": rounds})


def test_sensitivity_grid_cells_on_ray(local_ray, tmp_path, monkeypatch, capsys):
    """`python -m experiments.grasp_sensitivity run --ray`: each missing cell is one task
    writing <out>/<cell>.json (a stand-in cell here: a real one takes minutes); a rerun
    computes nothing."""
    import experiments.grasp_sensitivity as grid

    monkeypatch.setattr(grid, "run_cell", _fake_cell)
    monkeypatch.setattr(grid, "summarise", lambda out: {"cells": {}})
    cells = grid.CELLS[:3]
    args = ["run", "--cells", ",".join(cells), "--out", str(tmp_path), "--seeds", "3",
            "--ray"]
    assert grid.main(args) == 0
    for cell in cells:
        doc = io.load_json(tmp_path / f"{cell}.json")
        assert doc["cell"] == cell and doc["seeds"] == 3 and doc["pid"] != os.getpid()
    (tmp_path / f"{cells[1]}.json").unlink()
    kept = (tmp_path / f"{cells[0]}.json").stat().st_mtime_ns
    assert grid.main(args) == 0
    assert (tmp_path / f"{cells[1]}.json").exists()
    assert (tmp_path / f"{cells[0]}.json").stat().st_mtime_ns == kept
    with pytest.raises(SystemExit, match="--deadline"):
        grid.main(args + ["--deadline", "10"])


def _fake_setting(i, knobbed, objects, seeds, rounds, explore, backend, run_dir) -> None:
    io.save_json(Path(run_dir) / "done.json", {"setting": i, "pid": os.getpid()})


def test_baselines_tune_settings_on_ray(local_ray, tmp_path, monkeypatch):
    """`python -m experiments.grasp_baselines tune --ray`: the three settings are tasks (a
    stand-in setting here: a real one takes minutes), then read back by the usual loop."""
    import types

    import experiments.grasp_baselines as grid

    seen = []

    def read_back(config, specs, run_dir, theta0, progress):
        doc = io.load_json(Path(run_dir) / "done.json")  # written by the task
        assert doc["pid"] != os.getpid()
        seen.append(doc["setting"])
        q, o, r = len(config.policies), len(specs), config.rounds
        lowvar = np.full((r + 1, o, q, 2), 0.1 * doc["setting"], np.float32)
        return {"results": types.SimpleNamespace(lowvar_eval=lowvar,
                                                 explore_success=lowvar[1:])}, 0.0

    monkeypatch.setattr(grid, "tune_setting", _fake_setting)
    monkeypatch.setattr(grid, "_run", read_back)
    grid.main(["tune", "--out", str(tmp_path), "--tune-seeds", "2", "--tune-rounds", "1",
               "--ray", "--no-progress"])
    assert seen == [0, 1, 2]
    tuned = json.loads((tmp_path / "tuned.json").read_text())
    assert all(w > 0 for w in tuned["wall_s"])  # the tasks' seconds, not the read-back's
    with pytest.raises(SystemExit):
        grid.main(["collect", "--out", str(tmp_path), "--ray"])  # tune and run only


def test_baselines_run_on_ray_goes_through_the_learn_units(local_ray, tmp_path, monkeypatch):
    """`python -m experiments.grasp_baselines run --ray`: the reported run's objects as
    learn_units (whose results equal the single-process run: the learn test above); a
    unit failing stops it in one line (a stand-in for learn_units.run here)."""
    import experiments.grasp_baselines as grid
    from sern_jax.grasp.online import learn_units

    seen = {}

    def fake(config, specs, run_dir, *, theta0, ray, progress):
        seen.update(objects=[s.name for s in specs], run_dir=run_dir, ray=ray)
        raise distributed.UnitFailedError("object_box", "RuntimeError: stand-in")

    monkeypatch.setattr(learn_units, "run", fake)
    monkeypatch.setattr(grid, "_run", lambda *a: pytest.fail("ran without Ray"))
    with pytest.raises(SystemExit, match=r"^--ray: unit object_box failed: RuntimeError"):
        grid.main(["run", "--out", str(tmp_path), "--untuned", "--objects", "2", "--ray",
                   "--ray-retries", "1", "--no-progress"])
    assert len(seen["objects"]) == 2 and seen["run_dir"] == tmp_path / "run"
    assert seen["ray"].max_retries == 1


# `sern grasp learn --ray`: one task per object. Shipped θ0, a tiny run (2 objects x 2
# learners x 2 seeds x 2 rounds of 3 grasps); ~1 min on the shared 2 cores.
# (--explore = --evaluate and no low-variance evaluation: fewer shapes, fewer compiles)
LEARN = ["grasp", "learn", "box", "triangular_prism", "--policies", "sern,greedy", "--seeds",
         "2", "--rounds", "2", "--explore", "2", "--evaluate", "2", "--eval-poses", "0",
         "--fit-steps", "4", "--no-figures", "--no-progress"]


def _learn_arrays(run_dir: Path) -> dict:
    arrays = {f"results/{k}": v for k, v in _arrays(run_dir / "results.npz").items()}
    arrays.update({f"checkpoint/{k}": v for k, v in
                   _arrays(run_dir / "checkpoint.npz").items()})
    return arrays


def _unit_fails_for_box(config, spec, out_dir, theta0) -> None:
    """A learn unit that raises for the box and runs the real unit otherwise."""
    if spec.name == "box":
        raise RuntimeError("injected failure on the box")
    from sern_jax.grasp.online import learn_units

    learn_units.run_unit(config, spec, out_dir, theta0)


def _unit_killed_after_round_1(config, spec, out_dir, theta0) -> None:
    """A learn unit whose worker process is killed (SIGKILL) right after the box's round-1
    checkpoint, on the first attempt; Ray's retry resumes the unit from that checkpoint."""
    from sern_jax.grasp.online import checkpoint, learn_units

    marker = Path(out_dir).parent.parent / f"{spec.name}.killed"
    real = checkpoint.save

    def save(path, fingerprint, results, rewards, next_round):
        real(path, fingerprint, results, rewards, next_round)
        if spec.name == "box" and next_round == 2 and not marker.exists():
            marker.write_text("killed once after round 1")
            os.kill(os.getpid(), signal.SIGKILL)

    checkpoint.save = save
    try:
        learn_units.run_unit(config, spec, out_dir, theta0)
    finally:
        checkpoint.save = real


def _learn_single_and_on_ray_with_a_killed_worker(tmp_path, capsys, monkeypatch):
    """The tiny learning run in one process (``one``) and on Ray (``par``), the box's worker
    killed mid-unit once (retried); checks they are equal; returns (one, par, single arrays)."""
    from sern_jax.grasp.online import learn_units

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    one, par = tmp_path / "one", tmp_path / "ray"
    assert main(LEARN + ["--out", str(one)]) == 0
    # the box's worker is killed mid-unit (after round 1) once: retried, same results
    monkeypatch.setattr(learn_units, "run_unit", _unit_killed_after_round_1)
    assert main(LEARN + ["--ray", "--out", str(par)]) == 0
    monkeypatch.undo()
    assert (par / "box.killed").exists()
    assert "Ray: 2 objects" in capsys.readouterr().out
    single = _learn_arrays(one)
    _assert_same_arrays(single, _learn_arrays(par))
    assert (io.load_json(one / "table.json")["table"] ==
            io.load_json(par / "table.json")["table"])
    assert sorted(p.name for p in (par / "units").iterdir()) == [
        "object_box", "object_triangular_prism"]
    # the workers' compile cache: this user's, never inside the run directory
    assert any((tmp_path / "cache" / "sern_jax" / "jax").iterdir())
    assert not (par / ".jax_cache").exists()
    return one, par, single


@pytest.mark.slow  # ~190 s on the 2 cores beside the other test worker (Ray workers compile
# the learners); the default run keeps Ray equal to one process through the regret and dataset
# commands, a killed worker retried and a failing unit through run_units
def test_learn_on_ray_equals_single_process_with_a_killed_worker_retried(
        local_ray, tmp_path, capsys, monkeypatch):
    _, par, single = _learn_single_and_on_ray_with_a_killed_worker(tmp_path, capsys,
                                                                   monkeypatch)
    # a finished run: nothing runs (the units are not even looked at), same files
    shutil.rmtree(par / "units")
    assert main(LEARN + ["--ray", "--out", str(par)]) == 0
    assert "Ray:" not in capsys.readouterr().out and not (par / "units").exists()
    _assert_same_arrays(single, _learn_arrays(par))


@pytest.mark.slow  # four more learning runs on Ray (~2 min on the 2 cores beside the suite)
def test_learn_on_ray_stops_on_a_failing_unit_resumes_and_continues_a_serial_run(
        local_ray, tmp_path, capsys, monkeypatch):
    from sern_jax.grasp.online import learn_units

    one, par, single = _learn_single_and_on_ray_with_a_killed_worker(tmp_path, capsys,
                                                                     monkeypatch)
    # a run stopped before its units were joined (box's unit lost), and a unit that keeps
    # failing: one line naming it, exit 1; the finished unit is kept
    kept = (par / "units" / "object_triangular_prism" / "checkpoint.npz").stat().st_mtime_ns
    for name in ("units/object_box/checkpoint.npz", "checkpoint.npz", "results.npz"):
        (par / name).unlink()
    monkeypatch.setattr(learn_units, "run_unit", _unit_fails_for_box)
    assert main(LEARN + ["--ray", "--out", str(par)]) == 1
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("sern: error: --ray: unit object_box "), err
    assert "RuntimeError: injected failure on the box" in err[0]
    assert not (par / "units" / "object_box" / "checkpoint.npz").exists()
    assert not (par / "checkpoint.npz").exists()  # nothing joined while a unit is missing
    assert (par / "units" / "object_triangular_prism" /
            "checkpoint.npz").stat().st_mtime_ns == kept
    monkeypatch.undo()

    # resume with the same command: only the box runs, the results are the same
    assert main(LEARN + ["--ray", "--out", str(par)]) == 0
    assert "Ray: 1 objects" in capsys.readouterr().out
    assert (par / "units" / "object_triangular_prism" /
            "checkpoint.npz").stat().st_mtime_ns == kept
    _assert_same_arrays(single, _learn_arrays(par))

    # a run left part-way without --ray (its checkpoint after round 1) continues on Ray:
    # split into units at round 2, each replays round 1 and runs round 2
    from sern_jax.grasp.online import checkpoint

    saved = _arrays(one / "checkpoint.npz")
    results = checkpoint.RoundResults(*(saved[f] for f in checkpoint.RoundResults._fields))
    results, rewards = checkpoint.through(results, saved["explore_reward"], 2)
    part = tmp_path / "part"
    part.mkdir()
    checkpoint.save(part / "checkpoint.npz", str(saved["fingerprint"]), results, rewards, 2)
    assert main(LEARN + ["--ray", "--out", str(part)]) == 0
    assert "Ray: 2 objects" in capsys.readouterr().out
    _assert_same_arrays(single, _learn_arrays(part))


def test_learn_ray_flags_are_one_line(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(LEARN + ["--ray-cpus", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ray-cpus" in err and "add --ray" in err, err
    assert not out.exists()


# fault injection: these unit functions travel by value (tests/ is not importable by workers)
try:
    from ray import cloudpickle  # Ray ships its own
except ImportError:
    pass
else:
    cloudpickle.register_pickle_by_value(sys.modules[__name__])


def _unit_ok(path: str, value: int) -> None:
    io.save_npz(path, value=np.int64(value))


def _unit_fails(path: str, message: str) -> None:
    raise ValueError(message)


def _unit_dies_first_time(path: str, marker: str) -> None:
    """Kills its own worker process on the first attempt (as `kill -9` would)."""
    if not os.path.exists(marker):
        Path(marker).write_text("died once")
        os.kill(os.getpid(), signal.SIGKILL)
    io.save_npz(path, value=np.int64(7))


def test_killed_worker_is_retried(local_ray, tmp_path):
    units = [distributed.Unit("dies", _unit_dies_first_time,
                              (str(tmp_path / "dies.npz"), str(tmp_path / "marker"))),
             distributed.Unit("ok", _unit_ok, (str(tmp_path / "ok.npz"), 1))]
    distributed.run_units(units, distributed.RayConfig(max_retries=2), tmp_path,
                          progress=False, log=lambda s: None)
    assert int(io.load_npz(tmp_path / "dies.npz")["value"]) == 7
    assert (tmp_path / "marker").exists()


def test_worker_that_keeps_dying_stops_the_run_in_one_line(local_ray, tmp_path):
    units = [distributed.Unit("shard_00003.npz", _unit_dies_first_time,
                              (str(tmp_path / "dies.npz"), str(tmp_path / "marker")))]
    with pytest.raises(distributed.UnitFailedError) as info:
        distributed.run_units(units, distributed.RayConfig(max_retries=0), tmp_path,
                              progress=False, log=lambda s: None)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1
    assert "shard_00003.npz" in msg and "--ray-retries 0" in msg
    assert not (tmp_path / "dies.npz").exists()


def test_failing_unit_stops_the_run_in_one_line_and_keeps_finished_units(local_ray, tmp_path):
    ok = [distributed.Unit(f"ok{i}", _unit_ok, (str(tmp_path / f"ok{i}.npz"), i))
          for i in range(2)]
    distributed.run_units(ok, distributed.RayConfig(), tmp_path, progress=False,
                          log=lambda s: None)
    bad = distributed.Unit("cell_6N_clean", _unit_fails, ("x", "the simulator diverged"))
    with pytest.raises(distributed.UnitFailedError) as info:
        distributed.run_units([bad, *ok], distributed.RayConfig(max_retries=3), tmp_path,
                              progress=False, log=lambda s: None)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1
    assert "cell_6N_clean" in msg and "ValueError: the simulator diverged" in msg
    for i in range(2):
        assert int(io.load_npz(tmp_path / f"ok{i}.npz")["value"]) == i


def test_failing_unit_through_the_command_is_exit_1_one_line(local_ray, tmp_path, capsys,
                                                             monkeypatch):
    from sern_jax.experiment import regret

    # the units point at a function that raises (it travels by value, from this module)
    monkeypatch.setattr(regret, "compute_chunk",
                        _unit_fails_any)
    out = tmp_path / "r"
    assert main(TINY + ["--ray", "--out", str(out)]) == 1
    # (Ray may forward earlier tests' worker warnings to stderr: look at sern's own line)
    stderr = capsys.readouterr().err
    err = _error_lines(stderr)
    assert len(err) == 1 and err[0].startswith("sern: error: --ray: unit softmax__seeds_"), err
    assert "RuntimeError: injected chunk failure" in err[0]
    # the other tasks are stopped quietly: force-cancelled (no KeyboardInterrupt inside a
    # running worker, which could abort it with a forwarded "Fatal Python error") and their
    # outcomes collected (no "Unhandled error" from Ray for siblings that failed too)
    assert "Fatal Python error" not in stderr and "Unhandled error" not in stderr, stderr


def _unit_fails_any(*args) -> None:
    raise RuntimeError("injected chunk failure")


# ----------------------------------------------------------------------- two-node cluster


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_node_loopback_cluster_with_a_killed_worker(tmp_path):
    """``ray start --head`` on a loopback port plus a second ``ray start --address`` node
    (token auth disabled: loopback only), a regret sweep with SPREAD scheduling while a
    worker process is killed, and a tiny D0 across both nodes: the results equal the
    single-process run."""
    pytest.importorskip("ray")
    ray_bin = Path(sys.executable).with_name("ray")
    port = _free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}  # loopback test only
    one, par = tmp_path / "one", tmp_path / "ray"
    flags = ["regret", "--policies", "softmax,greedy,ucb1", "-T", "2000", "-S", "96",
             "--chunk-size", "8", "--no-figures", "--no-progress"]
    assert main(flags + ["--out", str(one)]) == 0
    try:
        subprocess.run([str(ray_bin), "start", "--head", "--node-ip-address=127.0.0.1",
                        f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
                        "--disable-usage-stats"], env=env, check=True, capture_output=True,
                       timeout=120)
        subprocess.run([str(ray_bin), "start", f"--address=127.0.0.1:{port}",
                        "--node-ip-address=127.0.0.1", "--num-cpus=1",
                        "--disable-usage-stats"], env=env, check=True, capture_output=True,
                       timeout=120)
        code = (
            "import sys\n"
            "from sern_jax.infra import distributed\n"
            "distributed_run = distributed.run_units\n"
            "def spread(units, config, run_dir, **kw):\n"
            "    import dataclasses\n"
            "    return distributed_run(units, dataclasses.replace(config, spread=True),\n"
            "                           run_dir, **kw)\n"
            "distributed.run_units = spread\n"
            "from sern_jax.commands.main import main\n"
            f"sys.exit(main({flags + ['--ray', f'127.0.0.1:{port}', '--out', str(par)]!r}))\n")
        driver = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        killed = _kill_one_worker(driver, timeout=240)
        text, _ = driver.communicate(timeout=600)
        assert driver.returncode == 0, text[-3000:]
        assert killed, "no worker process was found to kill"
        assert "on 2 CPUs (2 nodes)" in text, text[-3000:]
        _assert_same_arrays(_arrays(one / "results.npz"), _arrays(par / "results.npz"))

        # a tiny D0 across both nodes (one object per shard, SPREAD), against this process's
        d0_one, d0_par = tmp_path / "d0-one", tmp_path / "d0-ray"
        from sern_jax.grasp.model import dataset

        config = dataset.DatasetConfig(num_objects=4, poses_per_object=1, objects_per_shard=1)
        dataset.generate(config, d0_one, progress=False, log=lambda s: None)
        code = (
            "from sern_jax.infra import distributed\n"
            "from sern_jax.grasp.model import dataset\n"
            "config = dataset.DatasetConfig(num_objects=4, poses_per_object=1, "
            "objects_per_shard=1)\n"
            f"dataset.generate(config, {str(d0_par)!r}, progress=False, ray=distributed."
            f"RayConfig(address='127.0.0.1:{port}', spread=True))\n")
        out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, text=True,
                             capture_output=True, timeout=600)
        assert out.returncode == 0, (out.stdout + out.stderr)[-3000:]
        assert "Ray: 4 shards" in out.stdout and "(2 nodes)" in out.stdout, out.stdout
        for path in dataset.shard_paths(d0_one, config):
            _assert_same_arrays(_arrays(path), _arrays(d0_par / path.name))
    finally:
        subprocess.run([str(ray_bin), "stop", "--force"], env=env, capture_output=True,
                       timeout=120)


def _kill_one_worker(driver: subprocess.Popen, timeout: float) -> bool:
    """SIGKILLs one Ray worker process that is running a task (``ray::_call_unit``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and driver.poll() is None:
        ps = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
        pids = [int(line.split()[0]) for line in ps.splitlines()
                if "ray::_call_unit" in line and "IDLE" not in line]
        if pids:
            time.sleep(1.0)  # let it get into the computation
            try:
                os.kill(pids[0], signal.SIGKILL)
                return True
            except ProcessLookupError:
                continue
        time.sleep(0.2)
    return False
