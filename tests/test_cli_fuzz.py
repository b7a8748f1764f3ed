"""Bad values for every command's flags: exit 2, one line on stderr naming the flag, no
traceback, nothing written, and quickly (everything is checked before any work). A fixed list
of cases found by hand, and a property test over every flag of every command and subcommand
(random strings, empties, huge and tiny numbers, NaN, inf, negatives, lists with holes) that
also asserts nothing compiled."""

import os
import time

import pytest

from sern_jax.commands import main as cli

REGRET = ["regret", "--policies", "softmax", "--arms", "3", "--horizon", "20", "--seeds", "2",
          "--no-progress", "--no-figures", "--out", "run"]
CHECK = ["check", "--quick", "--only", "t1_expected_count", "--no-figures", "--out", "runs"]
BENCH_BANDIT = ["bench", "bandit", "--json", "--arms", "4", "--horizon", "10", "--seeds", "4",
                "--numpy-seeds", "0", "--general-repeats", "0"]
BENCH_GRASP = ["bench", "grasp", "--json", "--quick"]
SHOW = ["grasp", "show", "box", "--no-render", "--trials", "1", "--out", "show"]

CASES = [
    # (base argv, extra argv, text the message must contain)
    (REGRET, ["--arms", "1"], "--arms"),
    (REGRET, ["--arms", "100000000"], "--arms"),
    (REGRET, ["--horizon", "0"], "--horizon"),
    (REGRET, ["--horizon", "99999999999999"], "--horizon"),
    (REGRET, ["--float64", "--horizon", "99999999999999"], "--horizon"),
    (REGRET, ["--seeds", "0"], "--seeds"),
    (REGRET, ["--seeds", "99999999999999"], "--seeds"),
    (REGRET, ["--alpha", "0"], "--alpha"),
    (REGRET, ["--alpha", "nan"], "--alpha"),
    (REGRET, ["--alpha", "1e-40"], "--alpha"),
    (REGRET, ["--alpha", "1e-300"], "1e-300"),
    (REGRET, ["--epsilon", "2"], "--epsilon"),
    (REGRET, ["--contexts", "3", "--gap", "-0.1"], "--gap"),
    (REGRET, ["--contexts", "3", "--gap", "nan"], "--gap"),
    (REGRET, ["--contexts", "3", "--means", "0.1,0.2,0.3"], "--means"),
    (REGRET, ["--means", "0.1,0.2"], "--means"),
    (REGRET, ["--policies="], "--policies"),
    (REGRET, ["--policies", "softmax,bogus"], "bogus"),
    (REGRET, ["--estimator", "nn"], "nn"),
    (REGRET, ["--schedule", "nope"], "nope"),
    (REGRET, ["--seed", "99999999999999999999"], "--seed"),
    (REGRET, ["--seed", "-1"], "--seed"),
    (REGRET, ["--devices", "0"], "--devices"),
    (REGRET, ["--devices", "4"], "--devices"),
    (REGRET, ["--chunk-size", "0"], "--chunk-size"),
    (REGRET, ["--checkpoints", "0"], "--checkpoints"),
    (REGRET, ["--out", "a_file"], "--out"),
    (REGRET, ["--out", "/proc/x"], "--out"),
    (CHECK, ["--seeds", "1"], "--seeds"),
    (CHECK, ["--seeds", "99999999999"], "--seeds"),
    (CHECK, ["--alpha", "0.7"], "--alpha"),
    (CHECK, ["--seed", "-1"], "--seed"),
    (CHECK, ["--json-out", "."], "--json-out"),
    (CHECK, ["--json-out", "/proc/x/y.json"], "--json-out"),
    (CHECK, ["--json-out", "/proc/x.json"], "--json-out"),
    (CHECK, ["--out", "/proc"], "--out"),
    (CHECK, ["--out", "a_file"], "--out"),
    (CHECK, ["--out", "/proc/x"], "--out"),
    (BENCH_BANDIT, ["--arms", "1000000000"], "--arms"),
    (BENCH_BANDIT, ["--arms", "1"], "--arms"),
    (BENCH_BANDIT, ["--seeds", "1000000000000"], "--seeds"),
    (BENCH_BANDIT, ["--horizon", "16777216"], "--horizon"),
    (BENCH_BANDIT, ["--alpha", "0"], "--alpha"),
    (BENCH_BANDIT, ["--repeats", "0"], "--repeats"),
    (BENCH_BANDIT, ["--numpy-seeds", "1"], "--numpy-seeds"),
    (BENCH_BANDIT, ["--seed", "99999999999999999999"], "--seed"),
    (BENCH_GRASP, ["--native-batch", "0"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch=-4"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch", "abc"], "--native-batch"),
    (BENCH_GRASP, ["--native-batch", "1000000000"], "--native-batch"),
    (BENCH_GRASP, ["--repeats", "0"], "--repeats"),
    (BENCH_GRASP, ["--agreement", "-1"], "--agreement"),
    (BENCH_GRASP, ["--out", "."], "--out"),
    (BENCH_GRASP, ["--agreement", "1", "--agreement-objects", "no_such"], "no_such"),
    (SHOW, ["--trials", "-1"], "--trials"),
    (SHOW, ["--trials", "1000000000"], "--trials"),
    (SHOW, ["--seed", "99999999999999999999"], "--seed"),
    (SHOW, ["--out", "a_file"], "--out"),
    (["grasp", "show", "box_99999999999999999999_0", "--no-render"], [], "box_9999"),
]


@pytest.mark.parametrize("base,extra,flag", CASES,
                         ids=[" ".join(b[:2] + e) for b, e, _ in CASES])
def test_bad_flag_value(base, extra, flag, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_file").write_text("keep")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    t0 = time.perf_counter()
    assert _main(base + extra) == 2
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert flag in lines[0] and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "a_file").read_text() == "keep"
    assert elapsed < 20, elapsed  # refused up front (first call of a kind pays the imports)


# ----------------------------------------------------------------------------- grasp commands
# Every case of the probe (the silent NaN of --alpha 1e-300, sizes that ran out of
# memory or never ended, output paths that failed after the work, argparse's usage block), all
# refused in one line naming the flag, exit 2, nothing written, before any compile.

LEARN = ["grasp", "learn", "pipe_tee", "--no-progress", "--no-figures", "--out", "learn"]
DATASET = ["grasp", "dataset", "--no-progress", "--out", "d0new"]
PRETRAIN = ["grasp", "pretrain", "--no-progress", "--data", "d0", "--out", "theta"]
SCREEN = ["grasp", "screen", "box", "--no-progress"]
REPRODUCE = ["reproduce", "--quick", "--no-progress"]

GRASP_CASES = [
    (LEARN, ["--alpha", "1e-300"], "--alpha"),
    (LEARN, ["--alpha", "1e-40"], "--alpha"),
    (LEARN, ["--alpha", "nan"], "--alpha"),
    (LEARN, ["--alpha", "inf"], "--alpha"),
    (LEARN, ["--alpha", "0"], "--alpha"),
    (LEARN, ["--alpha", "-0.05"], "--alpha"),
    (LEARN, ["--epsilon", "2"], "--epsilon"),
    (LEARN, ["--epsilon", "nan"], "--epsilon"),
    (LEARN, ["--epsilon", "1e-45"], "--epsilon"),
    (LEARN, ["--alpha0", "1e-39"], "--alpha0"),
    (LEARN, ["--p", "1"], "--p"),
    (LEARN, ["--p", "nan"], "--p"),
    (LEARN, ["--policies", "sern_log", "--alpha0", "2e-38", "--p", "0.9"], "--alpha0"),
    (LEARN, ["--policies", "sern_log", "--rounds", "1", "--explore", "1"], "--rounds"),
    (LEARN, ["--policies", "sern,bogus"], "bogus"),
    (LEARN, ["--policies", "sern,sern"], "policies"),
    (LEARN, ["--ucb-width", "1e-39"], "--ucb-width"),
    (LEARN, ["--ucb-width", "nan"], "--ucb-width"),
    (LEARN, ["--lambda-prior", "1e-300"], "--lambda-prior"),
    (LEARN, ["--lambda-prior", "inf"], "--lambda-prior"),
    (LEARN, ["--decay-alpha0", "1e-40"], "--decay-alpha0"),
    (LEARN, ["--decay-epsilon0", "1e39"], "--decay-epsilon0"),
    (LEARN, ["--nu", "nan"], "--nu"),
    (LEARN, ["--ensemble-size", "0"], "--ensemble-size"),
    (LEARN, ["--policies", "ensemble_ts", "--ensemble-size", "1024", "--seeds", "1000"],
     "--ensemble-size"),
    (LEARN, ["--eval-poses", "1000000000"], "--eval-poses"),
    (LEARN, ["--eval-poses", "-1"], "--eval-poses"),
    (LEARN, ["--eval-trials", "100000000"], "--eval-trials"),
    (LEARN, ["--regret-trials", "100000000"], "--regret-trials"),
    (LEARN, ["--regret-trials", "-3"], "--regret-trials"),
    (LEARN, ["--seeds", "0"], "--seeds"),
    (LEARN, ["--seeds", "abc"], "--seeds"),
    (LEARN, ["--seeds", "100000000"], "--seeds"),
    (LEARN, ["--rounds", "0"], "--rounds"),
    (LEARN, ["--explore", "0"], "--explore"),
    (LEARN, ["--explore", "1000000"], "--explore"),
    (LEARN, ["--evaluate", "0"], "--evaluate"),
    (LEARN, ["--fit-steps", "0"], "--fit-steps"),
    (LEARN, ["--seed", "-1"], "--seed"),
    (LEARN, ["--core-set", "bogus"], "--core-set"),
    (LEARN, ["--backend", "gpu"], "--backend"),
    (LEARN, ["--json-out", "/proc/x.json"], "--json-out"),
    (LEARN, ["--json-out", "."], "--json-out"),
    (LEARN, ["--out", "a_file"], "--out"),
    (LEARN, ["--out", "/proc/x"], "--out"),
    (LEARN, ["--bogus-flag"], "--bogus-flag"),
    (LEARN, ["--mesh", "no_such.obj"], "no_such.obj"),
    (["grasp", "learn", "no_such_object", "--out", "learn"], [], "no_such_object"),
    (DATASET, ["--objects", "0"], "--objects"),
    (DATASET, ["--objects", "100000000"], "--objects"),
    (DATASET, ["--poses", "0"], "--poses"),
    (DATASET, ["--objects", "1", "--poses", "5000000"], "--poses"),
    (DATASET, ["--trials", "0"], "--trials"),
    (DATASET, ["--trials", "1000000"], "--trials"),
    (DATASET, ["--seed", "-1"], "--seed"),
    (DATASET, ["--backend", "gpu"], "--backend"),
    (DATASET, ["--out", "a_file"], "--out"),
    (DATASET, ["--out", "/proc/x"], "--out"),
    (PRETRAIN, ["--epochs", "0"], "--epochs"),
    (PRETRAIN, ["--epochs", "1000000000"], "--epochs"),
    (PRETRAIN, ["--batch-size", "0"], "--batch-size"),
    (PRETRAIN, ["--batch-size", "1000000000"], "--batch-size"),
    (PRETRAIN, ["--lr", "0"], "--lr"),
    (PRETRAIN, ["--lr", "nan"], "--lr"),
    (PRETRAIN, ["--lr", "1e-40"], "--lr"),
    (PRETRAIN, ["--core-k", "0"], "--core-k"),
    (PRETRAIN, ["--core-k", "513"], "--core-k"),
    (PRETRAIN, ["--heldout-trials", "100000000"], "--heldout"),
    (PRETRAIN, ["--heldout-objects", "100000000"], "--heldout"),
    (PRETRAIN, ["--screen-trials", "100000000"], "--screen"),
    (PRETRAIN, ["--seed", "-1"], "--seed"),
    (PRETRAIN, ["--data", "no_such_dir"], "--data"),
    (PRETRAIN, ["--out", "a_file"], "--out"),
    (PRETRAIN, ["--out", "/proc/x"], "--out"),
    (SCREEN, ["--poses", "0"], "--poses"),
    (SCREEN, ["--poses", "100000000"], "--poses"),
    (SCREEN, ["--trials", "100000000"], "--trials"),
    (SCREEN, ["--seed", "-1"], "--seed"),
    (SCREEN, ["--json-out", "/proc/x.json"], "--json-out"),
    (SCREEN, ["--json-out", "."], "--json-out"),
    (SCREEN, ["--mesh-units", "inch"], "--mesh-units"),
    (["grasp", "screen", "no_such_object"], [], "no_such_object"),
    (REPRODUCE, ["--out", "a_file"], "--out"),
    (REPRODUCE, ["--out", "/proc/x"], "--out"),
    (REPRODUCE, ["--bogus"], "--bogus"),
    (["grasp", "bogus"], [], "bogus"),
    (["bogus"], [], "bogus"),
]


def _main(argv) -> int:
    """cli.main's exit status, whether it returns it or argparse exits with it."""
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return exc.code


def _fake_dataset(root):
    """A D0 directory as `sern grasp dataset` leaves it: config.json (no shards needed: every
    pretrain case below is refused before the shards are read)."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import dataset

    config = dataset.DatasetConfig(num_objects=20, poses_per_object=4)
    io.save_json(root / "d0" / "config.json", {"config": config,
                                               "fingerprint": config.fingerprint()})


@pytest.mark.parametrize("base,extra,flag", GRASP_CASES,
                         ids=[" ".join(b[:2] + e) for b, e, _ in GRASP_CASES])
def test_bad_grasp_flag_value(base, extra, flag, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_file").write_text("keep")
    _fake_dataset(tmp_path)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    t0 = time.perf_counter()
    assert _main(base + extra) == 2
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert flag in lines[0] and "Traceback" not in err and "usage:" not in err
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "a_file").read_text() == "keep"
    assert elapsed < 20, elapsed  # refused up front (the first call pays the imports)


def test_help_is_unchanged(capsys):
    """--help still prints the full usage and the flags (exit 0)."""
    assert _main(["grasp", "learn", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage:") and "--alpha" in out and "--regret-trials" in out


# The probe's passing cases, kept as regressions: values at the edges are accepted.


@pytest.mark.parametrize("extra", [
    ["--alpha", "1.2e-38"], ["--alpha", "1e30"], ["--epsilon", "0"], ["--epsilon", "1"],
    ["--eval-poses", "0"], ["--regret-trials", "0"], ["--policies", "sern_log", "--p", "0.5"],
    ["--policies", "greedy", "--seeds", "1", "--rounds", "1", "--explore", "1"],
])
def test_edge_values_are_accepted(extra, tmp_path):
    from sern_jax.commands import grasp_learn
    from sern_jax.commands import main as cli_main

    parser = cli_main.build_parser()
    args = parser.parse_args(LEARN[:3] + extra + ["--out", str(tmp_path / "run")])
    config = grasp_learn.check_learn_args(args, num_objects=1)
    assert config.num_seeds >= 1
    assert not (tmp_path / "run").exists()


def _learn_run_dir(tmp_path, **arrays):
    from sern_jax.infra import io

    run = tmp_path / "learn"
    run.mkdir()
    io.save_npz(run / "checkpoint.npz", **arrays)
    io.save_json(run / "config.json", {"fingerprint": "someone else's"})
    return run


def _listing(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_learn_into_another_runs_directory_leaves_it_byte_identical(tmp_path, monkeypatch,
                                                                    capsys):
    """The probe's passing case: reuse with other settings is refused and the directory is
    left byte-identical (no lock file either)."""
    monkeypatch.chdir(tmp_path)
    run = _learn_run_dir(tmp_path, fingerprint="0123456789abcdef")
    before = _listing(run)
    assert _main(LEARN) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different learning run" in err[0]
    assert _listing(run) == before


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_learn_damaged_checkpoint_is_one_line(tmp_path, monkeypatch, capsys, how):
    import numpy as np

    monkeypatch.chdir(tmp_path)
    run = _learn_run_dir(tmp_path, fingerprint="x", big=np.arange(20_000.0))
    ckpt = run / "checkpoint.npz"
    data = ckpt.read_bytes()
    ckpt.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                      "random": np.random.default_rng(0).bytes(len(data))}[how])
    before = _listing(run)
    assert _main(LEARN) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checkpoint.npz is damaged" in err[0] and "delete it" in err[0]
    assert _listing(run) == before


def test_learn_run_directory_held_by_another_process(tmp_path, monkeypatch, capsys):
    """Two commands into one --out: the second is refused in one line naming the holder
    (a real second process holds the lock)."""
    import signal
    import subprocess
    import sys

    monkeypatch.chdir(tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom sern_jax.infra import io\n"
         "with io.run_lock(sys.argv[1], command='sern grasp learn (first)'):\n"
         "    print('locked', flush=True)\n    time.sleep(60)\n", str(tmp_path / "learn")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert _main(LEARN) == 2
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"pid {holder.pid}" in err[0] and "(first)" in err[0]
    assert sorted(p.name for p in (tmp_path / "learn").iterdir()) == [".sern.lock"]


# ----------------------------------------------------------------------------- property test
# Every flag of every command and subcommand the CLI has, given a value that no flag of its
# kind accepts, on an otherwise valid and small command line: exit 2, one stderr line naming
# the flag, no traceback, nothing written in the working directory, nothing compiled (a
# guard on JAX's compile entry point raises if anything reaches it).

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io as _io  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

NEURAL = ["regret", "--estimator", "neural", "--problem", "wheel", "--horizon", "50",
          "--seeds", "2", "--no-progress", "--no-figures", "--out", "run"]
BENCH_NEURAL = ["bench", "neural", "--json", "--seeds", "2", "--horizon", "50",
                "--loop-seeds", "0", "--loop-rounds", "50", "--repeats", "0"]
EXPERIMENT = ["experiment"]
# one valid, small command line per command and mode (the flags under test are appended)
BASES = {
    ("regret",): REGRET, ("regret", "neural"): NEURAL, ("check",): CHECK,
    ("reproduce",): REPRODUCE, ("experiment",): EXPERIMENT,
    ("bench", "bandit"): BENCH_BANDIT, ("bench", "grasp"): BENCH_GRASP,
    ("bench", "neural"): BENCH_NEURAL,
    ("grasp", "show"): SHOW, ("grasp", "dataset"): DATASET, ("grasp", "pretrain"): PRETRAIN,
    ("grasp", "screen"): SCREEN, ("grasp", "learn"): LEARN,
}
# flags whose value is free text (a run name): any text is a valid value
FREE_TEXT = {"--name"}
# input paths: a directory or file that does not exist
INPUT_PATHS = {"--data", "--theta0", "--mesh"}
# output paths: places nothing can be written
OUTPUT_PATHS = {"--out", "--json-out", "--results"}
# flags that take their value only with another flag (e.g. the agreement objects with
# --agreement N): the property test gives them that flag too
COMPANIONS = {"--agreement-objects": ["--agreement", "1"]}

_NUMBER_JUNK = st.one_of(
    st.sampled_from(["", " ", "nan", "-nan", "inf", "-inf", "1e400", "-1e400", "1,,2",
                     "0x1g", "--", "1e", "abc", "1 2"]),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz_!@#", min_size=1, max_size=8))
_INT_JUNK = st.one_of(_NUMBER_JUNK, st.sampled_from(["1.5", "1e3"]),
                      st.integers(min_value=10**20, max_value=10**30).map(str),
                      st.integers(max_value=-(10**20), min_value=-(10**30)).map(str))
_LIST_JUNK = st.one_of(st.sampled_from([",", ",,", "a,,b", ",x", "x,", " , ", "1,,2"]),
                       st.lists(st.sampled_from(["sern", "softmax", "greedy", "1", "0.5",
                                                 "box"]), min_size=1, max_size=3)
                       .map(lambda items: ",".join(items[:1] + [""] + items[1:])))
_NAME_JUNK = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1,
                     max_size=10).map(lambda t: "zz" + t)
# refused as a file and as a directory alike (a_file itself is a valid output file)
_BAD_OUTPUT = st.sampled_from(["/proc/x/y", "/proc/x", "a_file/x", "/proc"])
_BAD_INPUT = st.sampled_from(["no_such_dir", "a_file", "/proc/no_such"])


class _Compiled(BaseException):
    """JAX was asked to compile: a refusal must come before any compile."""


def _leaf_parsers():
    """(command path, parser) of every command and subcommand of ``sern``."""
    out = []

    def walk(parser, path):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out.append((path, parser))
        for action in subs:
            for name, child in action.choices.items():
                if child is not parser:
                    walk(child, path + (name,))

    walk(cli.build_parser(), ())
    return out


def _kind(action) -> str:
    flag = action.option_strings[0] if action.option_strings else None
    if flag in OUTPUT_PATHS:
        return "output"
    if flag in INPUT_PATHS:
        return "input"
    if action.choices is not None:
        return "choice"
    kind = getattr(action.type, "__name__", "")
    if action.type is int or kind.startswith("integer"):
        return "int"
    if action.type is float or kind == "number":
        return "float"
    if kind == "boolean":
        return "choice"
    return "list"


def _value_flags(parser):
    """The options of ``parser`` that take a value (the property test's subjects)."""
    return [a for a in parser._actions
            if a.option_strings and a.nargs != 0 and not isinstance(a, argparse._HelpAction)
            and a.option_strings[0] not in FREE_TEXT]


def _strategy(action):
    kind = _kind(action)
    if kind == "choice":
        choices = [str(c) for c in (action.choices or ())] + ["1", "0", "true", "false",
                                                              "yes", "no"]
        return _NAME_JUNK.filter(lambda t: t not in choices)
    return {"int": _INT_JUNK, "float": _NUMBER_JUNK, "list": _LIST_JUNK,
            "output": _BAD_OUTPUT, "input": _BAD_INPUT}[kind]


def _cases():
    """(base argv, flag action) for every value-taking flag of every command."""
    leaves = dict(_leaf_parsers())
    cases = []
    for key, base in BASES.items():
        path = key if key in leaves else key[:1]
        for action in _value_flags(leaves[path]):
            cases.append((key, action.option_strings[0]))
    missing = set(leaves) - {k if k in leaves else k[:1] for k in BASES}
    assert not missing, f"commands without a base command line here: {sorted(missing)}"
    return cases


_CASES = _cases()
_ACTIONS = {(key, flag): action for key in BASES
            for action in _value_flags(dict(_leaf_parsers())[key if key in dict(
                _leaf_parsers()) else key[:1]])
            for flag in action.option_strings[:1]}


@pytest.fixture
def compile_guard(monkeypatch):
    """Any JAX compile raises :class:`_Compiled` while a property test runs."""
    from jax._src import compiler

    def refuse(*args, **kwargs):
        raise _Compiled("a bad flag value reached a JAX compile")

    monkeypatch.setattr(compiler, "compile_or_get_cached", refuse)


def _run_refused(argv, flag):
    """Runs ``sern argv`` in a fresh directory; returns (status, stderr lines, tree changed,
    compiled)."""
    with tempfile.TemporaryDirectory() as tmp, contextlib.chdir(tmp):
        (Path(tmp) / "a_file").write_text("keep")
        _fake_dataset(Path(tmp))  # the D0 that PRETRAIN names
        before = sorted(str(p) for p in Path(tmp).rglob("*"))
        err = _io.StringIO()
        compiled = False
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(_io.StringIO()):
            try:
                status = _main(argv)
            except _Compiled:
                status, compiled = None, True
        after = sorted(str(p) for p in Path(tmp).rglob("*"))
        kept = (Path(tmp) / "a_file").read_text() == "keep"
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    return status, lines, before != after or not kept, compiled


@pytest.mark.parametrize("key, flag", _CASES, ids=[f"{' '.join(k)} {f}" for k, f in _CASES])
@settings(max_examples=2, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_every_flag_refuses_bad_values(key, flag, data, compile_guard):
    action = _ACTIONS[(key, flag)]
    value = data.draw(_strategy(action), label=flag)
    argv = BASES[key] + COMPANIONS.get(flag, []) + [f"{flag}={value}"]
    status, lines, wrote, compiled = _run_refused(argv, flag)
    assert not compiled, f"{argv}: compiled before refusing"
    assert status == 2, (argv, status, lines)
    assert len(lines) == 1, (argv, lines)
    assert flag in lines[0] and "Traceback" not in lines[0], (argv, lines)
    assert not wrote, f"{argv}: wrote into the working directory"


_POSITIONAL = [(["grasp", "show"], ["--no-render", "--trials", "1", "--out", "show"]),
               (["grasp", "learn"], ["--no-progress", "--no-figures", "--out", "learn"]),
               (["grasp", "screen"], ["--no-progress"]), (["experiment"], [])]


@pytest.mark.parametrize("head, tail", _POSITIONAL, ids=[" ".join(h) for h, _ in _POSITIONAL])
@settings(max_examples=2, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(name=_NAME_JUNK)
def test_every_positional_refuses_unknown_names(head, tail, name, compile_guard):
    status, lines, wrote, compiled = _run_refused(head + [name] + tail, name)
    assert not compiled and status == 2 and len(lines) == 1, (head, name, status, lines)
    assert name in lines[0] and not wrote, (head, name, lines)


# The experiment scripts, run as `sern experiment NAME ...`: each flag of their parsers (read
# by stopping the script's main at its parse), on a small valid command line.
SCRIPT_BASES = {
    "hard_objects": ["--poses", "1", "--trials", "1", "--out", "o.json"],
    "trial_checks": ["--poses", "1", "--candidates", "1", "--out", "o.json"],
    "core_set_forgetting": ["--out", "o"],
    "theory_on_grasping": ["--out", "o"],
    "make_theta0": ["--out", "o"],
    "grasp_learning": ["paper", "--results", "res", "--out", "o"],
}


class _Parsed(BaseException):
    """Raised in place of parsing: the script's parser is built and read."""


def _script_flags(name: str, base: list[str]):
    import importlib

    from sern_jax.infra import validate

    seen = {}
    real = validate.OneLineParser.parse_args

    def capture(self, args=None, namespace=None):
        seen["parser"] = self
        raise _Parsed

    validate.OneLineParser.parse_args = capture
    try:
        importlib.import_module(f"experiments.{name}").main(list(base))
    except _Parsed:
        pass
    finally:
        validate.OneLineParser.parse_args = real
    return [a for a in _value_flags(seen["parser"]) if a.choices is None]


_SCRIPT_CASES = [(name, action.option_strings[0], action)
                 for name, base in SCRIPT_BASES.items() for action in _script_flags(name, base)]


@pytest.mark.parametrize("name, flag, action", _SCRIPT_CASES,
                         ids=[f"{n} {f}" for n, f, _ in _SCRIPT_CASES])
@settings(max_examples=2, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_every_script_flag_refuses_bad_values(name, flag, action, data, compile_guard):
    value = data.draw(_strategy(action), label=flag)
    argv = ["experiment", name] + SCRIPT_BASES[name] + [f"{flag}={value}"]
    status, lines, wrote, compiled = _run_refused(argv, flag)
    assert not compiled, f"{argv}: compiled before refusing"
    assert status == 2 and len(lines) == 1, (argv, status, lines)
    assert flag in lines[0] and "Traceback" not in lines[0], (argv, lines)
    assert not wrote, f"{argv}: wrote into the working directory"
