"""The validation layer every command uses (sern_jax/infra/validate.py) and the refusals it
brings: typed flag parsers, flags with no effect in the chosen mode, size budgets of the
neural path, files of the wrong JSON shape, θ0 digests, run-directory locks, ``--ray``
addresses that do not answer, and the schedules a learner computes. Each refusal is one
line naming the flag (or the file), exit 2, nothing written, before any compile."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sern_jax.commands import main as cli
from sern_jax.infra import io, validate

ROOT = Path(__file__).resolve().parents[1]


def _main(argv) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return exc.code


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _refused(argv, tmp_path, monkeypatch, capsys, named: str) -> str:
    """Runs ``sern argv`` in ``tmp_path``: exit 2, one stderr line containing ``named``, no
    traceback, nothing written; returns the line."""
    monkeypatch.chdir(tmp_path)
    before = _tree(tmp_path)
    assert _main(argv) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert named in lines[0] and "Traceback" not in err, err
    assert _tree(tmp_path) == before
    return lines[0]


# ----------------------------------------------------------------------------- parsers


def test_typed_parsers_name_the_problem():
    parse = validate.int_in(1, 10)
    assert parse(" 3 ") == 3
    for bad in ("0", "11", "abc", "", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(bad)
    real = validate.float_in(0.0, 1.0)
    assert real("0.25") == 0.25
    for bad in ("nan", "inf", "-1", "2", "x", "1e400"):
        with pytest.raises(argparse.ArgumentTypeError):
            real(bad)
    assert validate.comma_list(" a, b ", "--x") == ["a", "b"]
    for bad, what in (("a,,b", "empty item"), (",", "empty item"), ("a,", "empty item"),
                      ("a,a", "twice"), ("", "empty")):
        with pytest.raises(ValueError, match=what) as info:
            validate.comma_list(bad, "--x")
        assert str(info.value).startswith("--x")
    assert validate.comma_list_of("1,2", "--h", int, "integers") == [1, 2]
    with pytest.raises(ValueError, match="--d .* twice"):
        validate.comma_list_of("0.5,0.50", "--d", float, "numbers")
    with pytest.raises(ValueError, match="--h must be a comma list of integers"):
        validate.comma_list_of("50,abc", "--h", int, "integers")
    for good in ("auto", "127.0.0.1:6379", "ray://head:10001", "[::1]:6379"):
        assert validate.ray_address(good) == good
    for bad in ("127.0.0.1:0", "127.0.0.1:70000", "host", ":80", "a b:1", "host:x"):
        with pytest.raises(argparse.ArgumentTypeError):
            validate.ray_address(bad)


def test_refuse_unused_names_the_flag():
    args = argparse.Namespace(hidden="50", p=None)
    with pytest.raises(ValueError, match="^--hidden has no effect with the tabular"):
        validate.refuse_unused(args, {"hidden": None, "p": None}, "with the tabular")
    validate.refuse_unused(argparse.Namespace(hidden=None), {"hidden": None}, "x")


def test_quiet_numerics_keeps_warnings_out(recwarn):
    import numpy as np

    with validate.quiet_numerics():
        np.float32(1e300) * np.float32(10)
        np.log(np.float64(-1))
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


@pytest.mark.parametrize("text", ['"x"', "[]", "null", "5", "not json", ""])
def test_read_json_object_refuses_the_wrong_shape(tmp_path, text):
    path = tmp_path / "config.json"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        validate.read_json_object(path, {"config": dict}, what="dataset config")
    message = str(info.value)
    assert str(path) in message and "\n" not in message


def test_read_json_object_checks_field_types(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"a": True, "b": 1}))
    with pytest.raises(ValueError, match="'a' holds true or false, not an integer"):
        validate.read_json_object(path, {"a": int})
    with pytest.raises(ValueError, match="no 'c' field"):
        validate.read_json_object(path, {"c": str})
    assert validate.read_json_object(path, {"b": (int, float)})["b"] == 1


# ----------------------------------------------------------------------------- sern regret

TAB = ["regret", "--policies", "softmax", "--arms", "3", "--horizon", "20", "--seeds", "2",
       "--no-progress", "--no-figures", "--out", "run"]
NEURAL = ["regret", "--estimator", "neural", "--problem", "wheel", "--horizon", "50",
          "--seeds", "2", "--no-progress", "--no-figures", "--out", "run"]


@pytest.mark.parametrize("argv, named", [
    (NEURAL + ["--epsilon", "2"], "--epsilon"),
    (NEURAL + ["--policies", "egreedy", "--epsilon", "-1"], "--epsilon"),
    (NEURAL + ["--deltas", "0.5,,0.7"], "--deltas"),
    (NEURAL + ["--hidden", "50,,50"], "--hidden"),
    (NEURAL + ["--policies", "sern,,greedy"], "--policies"),
    (NEURAL + ["--policies", "sern", "--p", "0.5"], "--p"),
    (NEURAL + ["--means", "0.1,0.2"], "--means"),
    (NEURAL + ["--schedule", "log"], "--schedule"),
    (NEURAL + ["--context-dim", "8"], "--context-dim"),  # the wheel's contexts are 2-d
    (NEURAL + ["--alpha", "1e300"], "--alpha"),
    (["regret", "--estimator", "neural", "--problem", "finite", "--horizon", "50",
      "--context-dim", "1000000000", "--out", "run"], "--context-dim"),
    (["regret", "--estimator", "neural", "--problem", "finite", "--horizon", "50",
      "--contexts", "1000000000", "--out", "run"], "--contexts"),
    (["regret", "--estimator", "neural", "--problem", "linear", "--horizon", "50",
      "--arms", "100000000", "--out", "run"], "--arms"),
    (["regret", "--estimator", "neural", "--problem", "linear", "--horizon", "50",
      "--arms", "4096", "--context-dim", "65536", "--hidden", "4096,4096",
      "--chunk-size", "1000", "--seeds", "1000", "--out", "run"], "--arms"),  # the budget
    (TAB + ["--hidden", "abc"], "--hidden"),
    (TAB + ["--learning-rate", "0.1"], "--learning-rate"),
    (TAB + ["--p", "-1"], "--p"),
    (TAB + ["--policies", "greedy", "--epsilon", "0.2"], "--epsilon"),
    (TAB + ["--gap", "0.2"], "--gap"),
    (TAB + ["--alpha", "1e300"], "--alpha"),
    (TAB + ["--means", "nan,0.5,0.3"], "--means"),
    (TAB + ["--means", "0.1,,0.3"], "--means"),
    (TAB + ["--ray", "127.0.0.1:70000"], "--ray"),
    (TAB + ["--ray", "no-port"], "--ray"),
])
def test_regret_refusals(argv, named, tmp_path, monkeypatch, capsys):
    t0 = time.perf_counter()
    _refused(argv, tmp_path, monkeypatch, capsys, named)
    assert time.perf_counter() - t0 < 30


def test_alpha_1e300_prints_no_numpy_warning(tmp_path, monkeypatch, capsys):
    line = _refused(TAB + ["--alpha", "1e300"], tmp_path, monkeypatch, capsys, "--alpha")
    assert "overflow" not in line.lower()


def test_neural_budget_is_estimated_from_the_flags():
    from sern_jax.experiment import neural_regret as nr

    small = nr.estimate(nr.NeuralRegretExperiment())
    assert 0 < small["memory_bytes"] < 2**30 and small["seconds"] < 86400
    big = nr.estimate(nr.NeuralRegretExperiment(problem="finite", num_contexts=2**24,
                                                context_dim=65_536))
    assert big["memory_bytes"] > 2**40


def test_unreachable_ray_address_fails_fast_in_one_line(tmp_path, monkeypatch, capsys):
    pytest.importorskip("ray")
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    line = _refused(TAB + ["--ray", f"127.0.0.1:{port}"], tmp_path, monkeypatch, capsys,
                    "--ray")
    assert "cannot join" in line and time.perf_counter() - t0 < 30


def test_ray_address_127_0_0_1_port_1_as_a_process(tmp_path):
    """The command of the report, as a user runs it: within 30 s, one line, nothing
    written (Ray's own log lines kept out)."""
    pytest.importorskip("ray")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "sern_jax.commands.main", *TAB,
                          "--ray", "127.0.0.1:1"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert time.perf_counter() - t0 < 30
    assert out.returncode == 2, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--ray 127.0.0.1:1" in lines[0], out.stderr
    assert list(tmp_path.iterdir()) == []


def test_ray_help_states_the_connection_bound(capsys):
    assert _main(["regret", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    from sern_jax.infra import distributed

    assert f"within {distributed.CONNECT_TIMEOUT_S:g} s" in text


def test_private_core_lock_dir_refuses_a_planted_one(tmp_path, monkeypatch):
    import tempfile

    from sern_jax.infra import distributed

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    mine = distributed.private_dir("sern-ray-cores")
    assert mine == tmp_path / f"sern-ray-cores-{os.getuid()}"
    assert mine.stat().st_mode & 0o777 == 0o700
    assert distributed.private_dir("sern-ray-cores") == mine  # reused
    target = tmp_path / "elsewhere"
    target.mkdir()
    (tmp_path / f"planted-{os.getuid()}").symlink_to(target)
    assert distributed.private_dir("planted") is None  # a symlink is never followed
    open_dir = tmp_path / f"open-{os.getuid()}"
    open_dir.mkdir(mode=0o777)
    os.chmod(open_dir, 0o777)
    assert distributed.private_dir("open") is None  # others could plant files in it


def test_local_ray_binds_to_loopback(monkeypatch):
    """The local Ray is started with loopback as its node address."""
    from sern_jax.infra import distributed

    calls = {}

    class FakeRay:
        class _private:  # noqa: N801 - ray._private
            class ray_constants:  # noqa: N801 - its switch that keeps a loopback node address
                ENABLE_RAY_CLUSTER = True

        @staticmethod
        def is_initialized():
            return False

        @staticmethod
        def init(**kwargs):
            calls.update(kwargs, cluster=FakeRay._private.ray_constants.ENABLE_RAY_CLUSTER)

    assert distributed._init(FakeRay, distributed.RayConfig()) is True
    assert calls["_node_ip_address"] == "127.0.0.1" and calls["address"] == "local"
    assert calls["cluster"] is False  # loopback is kept while it starts (Ray 2.60 would
    assert FakeRay._private.ray_constants.ENABLE_RAY_CLUSTER is True  # resolve it), restored
    assert calls["logging_level"] >= 40  # errors only: Ray's warnings stay off the terminal
    # (tests/infra/test_ray_network.py starts a real one and reads its listening sockets)


# ----------------------------------------------------------------------------- other commands


def test_bench_grasp_depth_batch_0_is_refused(tmp_path, monkeypatch, capsys):
    t0 = time.perf_counter()
    _refused(["bench", "grasp", "--json", "--depth-batch", "0"], tmp_path, monkeypatch,
             capsys, "--depth-batch")
    assert time.perf_counter() - t0 < 20


def test_check_only_bogus_names_the_flag(tmp_path, monkeypatch, capsys):
    _refused(["check", "--quick", "--only", "bogus", "--no-figures", "--out", "runs"],
             tmp_path, monkeypatch, capsys, "--only")


def test_check_json_out_held_by_another_check_is_refused(tmp_path, monkeypatch, capsys):
    """Two checks into one --json-out: the second is refused in one line naming the flag
    (a real second process holds the file's lock), so neither report is lost silently."""
    from sern_jax.commands import check

    target = tmp_path / "report.json"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.commands import check\n"
         "with check._file_lock(sys.argv[1], '--json-out'):\n"
         "    print('locked', flush=True)\n    time.sleep(60)\n", str(target)],
        stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(ValueError, match="^--json-out .* another sern check"), \
                check._file_lock(target, "--json-out"):
            pass
    finally:
        holder.kill()
        holder.wait()
    with check._file_lock(target, "--json-out"):  # free again once the holder died
        pass


def test_check_run_directories_of_one_second_differ(tmp_path):
    from sern_jax.commands import check

    args = argparse.Namespace(out=str(tmp_path), name=None, quick=True)
    first, second = check._new_run_dir(args), check._new_run_dir(args)
    assert first != second and first.is_dir() and second.is_dir()


# ----------------------------------------------------------------------------- trusted files


def _theta0_copy(tmp_path) -> Path:
    from sern_jax.grasp.model import artifacts

    d = tmp_path / "theta0"
    d.mkdir()
    for f in artifacts.FILES:
        shutil.copy(artifacts.DATA_DIR / f, d / f)
    return d


def test_shipped_manifest_carries_the_digest_of_theta0():
    import hashlib

    from sern_jax.grasp.model import artifacts

    manifest = json.loads((artifacts.DATA_DIR / artifacts.MANIFEST_FILE).read_text())
    blob = (artifacts.DATA_DIR / artifacts.THETA0_FILE).read_bytes()
    assert manifest["theta0_sha256"] == hashlib.sha256(blob).hexdigest()


def test_garbled_theta0_without_a_digest_is_refused(tmp_path):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    manifest = json.loads((d / "manifest.json").read_text())
    del manifest["theta0_sha256"]
    (d / "manifest.json").write_text(json.dumps(manifest))
    blob = bytearray((d / "theta0.msgpack").read_bytes())
    blob[-100] ^= 0x40  # a weight's byte changed: still valid msgpack
    (d / "theta0.msgpack").write_bytes(bytes(blob))
    with pytest.raises(ValueError, match="^--theta0 .*theta0_sha256") as info:
        artifacts.load_theta0(d)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("manifest", [{}, [], {"network_config": None, "theta0_sha256": "x"},
                                      "text", None])
def test_theta0_manifest_of_the_wrong_shape_is_one_line(tmp_path, manifest):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    (d / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError) as info:
        artifacts.load_theta0(d)
    assert "manifest.json" in str(info.value) and "--theta0" in str(info.value)


@pytest.mark.parametrize("screen", [{"objects": 5}, {"objects": [{"object": "box"}]},
                                    {"objects": [5]}, []])
def test_screen_json_of_the_wrong_shape_is_one_line(tmp_path, screen):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    artifacts.save_screen(d, screen)  # its digest recorded: the schema is what refuses it
    with pytest.raises(ValueError, match="screen.json") as info:
        artifacts.load_theta0(d)
    assert "\n" not in str(info.value) and "sha256" not in str(info.value)


def test_shipped_manifest_carries_the_digest_of_the_screen():
    import hashlib

    from sern_jax.grasp.model import artifacts

    manifest = json.loads((artifacts.DATA_DIR / artifacts.MANIFEST_FILE).read_text())
    blob = (artifacts.DATA_DIR / artifacts.SCREEN_FILE).read_bytes()
    assert manifest["screen_sha256"] == hashlib.sha256(blob).hexdigest()


def _edited_screen(d: Path) -> None:
    """One success rate of the screen changed: still valid JSON of the right shape."""
    screen = json.loads((d / "screen.json").read_text())
    screen["objects"][0]["greedy_success"] = 1.0 - screen["objects"][0]["greedy_success"]
    (d / "screen.json").write_text(json.dumps(screen, indent=2))


def test_an_edited_screen_is_refused(tmp_path):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    _edited_screen(d)
    with pytest.raises(ValueError, match=r"^--theta0 .*screen\.json does not match its "
                                         r"manifest") as info:
        artifacts.load_theta0(d)
    assert "\n" not in str(info.value)


def test_a_screen_without_a_digest_is_refused(tmp_path, monkeypatch, capsys):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    manifest = json.loads((d / "manifest.json").read_text())
    del manifest["screen_sha256"]
    (d / "manifest.json").write_text(json.dumps(manifest))
    _edited_screen(d)
    with pytest.raises(ValueError, match="^--theta0 .*screen_sha256"):
        artifacts.load_theta0(d)
    line = _refused(["grasp", "screen", "box", "--theta0", str(d)], tmp_path, monkeypatch,
                    capsys, f"--theta0 {d}")
    assert "screen_sha256" in line
    (d / "screen.json").unlink()  # no screen: nothing to vouch for, loads
    assert artifacts.load_theta0(d).screen is None


def test_a_recorded_screen_that_is_missing_is_refused(tmp_path):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    (d / "screen.json").unlink()
    with pytest.raises(ValueError, match="screen.json is missing"):
        artifacts.load_theta0(d)


def test_save_screen_and_install_record_the_digest(tmp_path):
    from sern_jax.grasp.model import artifacts

    d = _theta0_copy(tmp_path)
    screen = json.loads((d / "screen.json").read_text())
    screen["objects"] = screen["objects"][:3]
    artifacts.save_screen(d, screen)
    assert artifacts.load_theta0(d).screen == screen
    # a pretrain directory whose screen was written beside it without a digest: install
    # records the digest of the screen it installs
    manifest = json.loads((d / "manifest.json").read_text())
    del manifest["screen_sha256"]
    (d / "manifest.json").write_text(json.dumps(manifest))
    dst = artifacts.install(d, tmp_path / "dst")
    assert artifacts.load_theta0(dst).screen == screen
    # a source whose screen does not match its recorded digest is not installed
    artifacts.save_screen(d, screen)
    _edited_screen(d)
    with pytest.raises(ValueError, match="does not match its manifest"):
        artifacts.install(d, tmp_path / "dst2")
    assert not (tmp_path / "dst2").exists()


def test_screen_with_a_missing_theta0_names_the_flag(tmp_path, monkeypatch, capsys):
    _refused(["grasp", "screen", "box", "--theta0", "nowhere"], tmp_path, monkeypatch, capsys,
             "--theta0 nowhere")


@pytest.mark.parametrize("text", ["[]", "null", "5", '"x"', '{"config": "x"}',
                                  '{"config": {"bogus": 1}}'])
def test_dataset_config_of_the_wrong_type_is_one_line(tmp_path, monkeypatch, capsys, text):
    (tmp_path / "d0").mkdir()
    (tmp_path / "d0" / "config.json").write_text(text)
    _refused(["grasp", "dataset", "--no-progress", "--objects", "1", "--poses", "1",
              "--out", "d0"], tmp_path, monkeypatch, capsys, "d0")
    _refused(["grasp", "pretrain", "--no-progress", "--data", "d0", "--out", "theta"],
             tmp_path, monkeypatch, capsys, "--data d0")
    from sern_jax.grasp.model import dataset

    with pytest.raises(ValueError, match="config.json"):
        dataset.load(tmp_path / "d0")


# ----------------------------------------------------------------------------- learners


@pytest.mark.parametrize("name, flag, value", [("sern_decay", "--decay-alpha0", 1.1754944e-38),
                                               ("egreedy_decay", "--decay-epsilon0", 2e-37)])
def test_decaying_schedules_keep_float32_over_the_whole_horizon(name, flag, value):
    from sern_jax.learners import base, registry

    train = base.TrainConfig(horizon=100, fit_steps=1, batch_size=1, learning_rate=1e-3)
    config = registry.make_config(name, {flag.removeprefix("--").replace("-", "_"): value})
    with pytest.raises(ValueError, match=f"^{flag}"):
        registry.make(name, None, train, config)


def test_learn_decay_alpha0_is_refused_up_front(tmp_path, monkeypatch, capsys):
    t0 = time.perf_counter()
    _refused(["grasp", "learn", "pipe_tee", "--policies", "sern_decay", "--decay-alpha0",
              "1.1754944e-38", "--no-progress", "--out", "learn"], tmp_path, monkeypatch,
             capsys, "--decay-alpha0")
    assert time.perf_counter() - t0 < 20


# ----------------------------------------------------------------------------- locks


def test_run_lock_creates_and_locks_and_removes_only_its_own(tmp_path):
    run = tmp_path / "run"
    with pytest.raises(RuntimeError), io.run_lock(run, remove_unused=lambda p: True):
        assert (run / io.LOCK_FILE).exists()
        raise RuntimeError("fails before writing")
    assert not run.exists()  # this call created it: removed under the lock
    run.mkdir()
    (run / "keep").write_text("x")
    with pytest.raises(RuntimeError), io.run_lock(run, remove_unused=lambda p: True):
        raise RuntimeError("fails")
    assert (run / "keep").read_text() == "x"  # not created by this call: kept


def test_a_loser_never_removes_the_winners_directory(tmp_path):
    """Two runs at the same instant: the one refused never deletes the directory that the
    other created and holds, and no third process can take a second lock."""
    run = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import validate\n"
         "with validate.locked_run_dir(sys.argv[1]):\n"
         "    print('locked', flush=True)\n    time.sleep(60)\n", str(run)],
        stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(io.RunLockedError), validate.locked_run_dir(run):
            pass
        assert (run / io.LOCK_FILE).exists()  # the loser left it alone
        with pytest.raises(io.RunLockedError):
            io.refuse_if_locked(run)
        with pytest.raises(io.RunLockedError), io.run_lock(run):
            pass
    finally:
        holder.kill()
        holder.wait()
    io.refuse_if_locked(run)  # released by the kernel


def test_a_loser_that_created_the_directory_never_removes_it(tmp_path, monkeypatch):
    """The race of two runs started at the same instant, made exact: this process creates
    the directory, and the other takes its lock right before this process's ``flock``. The
    loser is refused and leaves the winner's directory (and lock) alone."""
    import fcntl

    run = tmp_path / "run"
    real_flock = fcntl.flock
    holders = []

    def flock(fd, op):
        if not holders:  # the winner locks between this process's mkdir and its flock
            holders.append(subprocess.Popen(
                [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import "
                 "validate\nwith validate.locked_run_dir(sys.argv[1]):\n"
                 "    print('locked', flush=True)\n    time.sleep(60)\n", str(run)],
                stdout=subprocess.PIPE, text=True, cwd=ROOT))
            assert holders[0].stdout.readline().strip() == "locked"
        return real_flock(fd, op)

    monkeypatch.setattr(fcntl, "flock", flock)
    try:
        with pytest.raises(io.RunLockedError), validate.locked_run_dir(run):
            pass
        assert holders and (run / io.LOCK_FILE).exists()  # the winner's directory is kept
        monkeypatch.setattr(fcntl, "flock", real_flock)
        with pytest.raises(io.RunLockedError), io.run_lock(run):  # and still locked
            pass
    finally:
        for holder in holders:
            holder.kill()
            holder.wait()


def test_a_lock_on_a_removed_directory_is_taken_again(tmp_path, monkeypatch):
    """A process whose lock file was removed (with its directory) between its open and its
    flock starts again, so it never holds a lock on a file no longer at the path."""
    import fcntl

    run = tmp_path / "run"
    real_flock = fcntl.flock
    calls = []

    def flock(fd, op):
        if not calls:  # the first holder removes the directory right before our flock
            calls.append(fd)
            shutil.rmtree(run)
        return real_flock(fd, op)

    monkeypatch.setattr(fcntl, "flock", flock)
    with io.run_lock(run):
        held = os.stat(run / io.LOCK_FILE)
        assert len(calls) == 1 and held.st_size > 0


def test_second_learn_on_a_locked_directory_refuses_before_compiling(tmp_path, monkeypatch,
                                                                    capsys):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import io\n"
         "with io.run_lock(sys.argv[1], command='sern grasp learn (first)'):\n"
         "    print('locked', flush=True)\n    time.sleep(60)\n", str(tmp_path / "learn")],
        stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "locked"
        from sern_jax.grasp.model import artifacts

        def no_theta0(*args, **kwargs):
            raise AssertionError("θ0 loaded: the lock was checked too late")

        monkeypatch.setattr(artifacts, "load_theta0", no_theta0)
        _refused(["grasp", "learn", "pipe_tee", "--no-progress", "--no-figures", "--out",
                  "learn"], tmp_path, monkeypatch, capsys, "(first)")
    finally:
        holder.kill()
        holder.wait()


# ----------------------------------------------------------------------------- scripts


@pytest.mark.parametrize("module, argv, named", [
    ("experiments.grasp_learning", ["paper", "--labels", "bogus", "--results", "res"],
     "--labels"),
    ("experiments.grasp_learning", ["paper", "--out", "/proc/x", "--results", "res"], "--out"),
    ("experiments.grasp_learning", ["paper", "--labels", "a,,b", "--results", "res"],
     "--labels"),
    ("experiments.grasp_learning", ["collect", "no_runs", "res"], "no_runs"),
    ("experiments.grasp_sensitivity", ["run", "--deadline", "nan", "--out", "s"], "--deadline"),
    ("experiments.grasp_sensitivity", ["run", "--deadline", "-5", "--out", "s"], "--deadline"),
    ("experiments.grasp_sensitivity", ["run", "--cells", "bogus", "--out", "s"], "--cells"),
    ("experiments.hard_objects", ["--seed", "-1"], "--seed"),
    ("experiments.hard_objects", ["--out", "/proc/x.json"], "--out"),
    ("experiments.trial_checks", ["--out", "/proc/x.json"], "--out"),
    ("experiments.make_theta0", ["--out", "/proc/x"], "--out"),
    ("experiments.core_set_forgetting", ["--out", "/proc/x"], "--out"),
    ("experiments.theory_on_grasping", ["--out", "/proc/x"], "--out"),
])
def test_experiment_scripts_validate_before_writing(module, argv, named, tmp_path,
                                                    monkeypatch, capsys):
    import importlib

    monkeypatch.chdir(tmp_path)
    main = importlib.import_module(module).main
    try:
        status = main(argv)
    except SystemExit as exc:
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and named in lines[0], err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
