"""The experiment scripts' bad input (``python -m experiments.NAME``, ``sern experiment NAME``):
one line on stderr naming the flag, exit status 2, nothing written, before JAX, MuJoCo or
flax is imported (so before any compile). Their parsers are ``validate.script_parser`` (the
``sern`` CLI's one-line parser) with ``validate.int_at_least`` counts."""

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("jax", "mujoco", "flax", "optax", "ray")

# In a fresh interpreter: import the script, call main(argv), report the exit status, what
# went to stderr and which heavy modules got imported (into the JSON file named first).
DRIVER = """
import contextlib, importlib, io, json, sys
out, name, argv = sys.argv[1], sys.argv[2], sys.argv[3:]
err = io.StringIO()
try:
    with contextlib.redirect_stderr(err):
        code = importlib.import_module(name).main(argv)
except SystemExit as exc:
    code = exc.code
except BaseException as exc:  # a traceback is a failure of this test
    code = "raised " + repr(exc)
with open(out, "w") as f:
    json.dump({"code": code, "err": err.getvalue(),
               "heavy": [m for m in HEAVY if m in sys.modules]}, f)
""".replace("HEAVY", repr(HEAVY))

CASES = [
    # (script, argv, text the one line must contain, refused before heavy imports)
    ("core_set_forgetting", ["--seeds", "abc"], "--seeds", True),
    ("core_set_forgetting", ["--seeds", "-1"], "--seeds", True),
    ("core_set_forgetting", ["--lr", "x"], "--lr", True),
    ("grasp_baselines", ["run", "--seeds", "abc"], "--seeds", True),
    ("grasp_baselines", ["run", "--seeds", "1"], "--seeds", True),
    ("grasp_baselines", ["run", "--objects", "0"], "--objects", True),
    ("grasp_baselines", ["bogus"], "bogus", True),
    ("grasp_learning", ["strong", "--seeds", "abc"], "--seeds", True),
    ("grasp_learning", ["strong", "--seeds", "-1"], "--seeds", True),
    ("grasp_learning", ["strong", "--regret-trials", "-1"], "--regret-trials", True),
    ("grasp_learning", ["summarise"], "dirs", True),
    ("grasp_sensitivity", ["run", "--seeds", "abc"], "--seeds", True),
    ("grasp_sensitivity", ["run", "--workers", "0"], "--workers", True),
    ("grasp_sensitivity", ["cell", "no_such_cell"], "no_such_cell", True),
    ("hard_objects", ["--poses", "-1"], "--poses", True),
    ("hard_objects", ["--trials", "abc"], "--trials", True),
    ("hard_objects", ["--threads", "0"], "--threads", True),
    ("make_theta0", ["--objects", "-1"], "--objects", True),
    ("make_theta0", ["--core-k", "abc"], "--core-k", True),
    ("make_theta0", ["--core-k", "100000"], "--core-k", False),  # the config's own range
    ("paper_table1", ["--bogus"], "--bogus", True),
    ("ray_scaling", ["--poses", "abc"], "--poses", True),
    ("ray_scaling", ["--per-worker", "0"], "--per-worker", True),
    ("ray_scaling", ["--workers", "1,x"], "--workers", True),
    ("ray_scaling", ["--mode", "d0-sampled", "--full-workers", "8,x"], "--full-workers", True),
    ("ray_scaling", ["--mode", "d0-sampled", "--full-workers", "8,1"], "--full-workers", True),
    ("ray_scaling", ["--mode", "default-d0", "--full-workers", ""], "--full-workers", True),
    ("ray_scaling", ["--mode", "d0-sampled", "--sample-seed", "-1"], "--sample-seed", True),
    ("ray_scaling", ["--mode", "d0-sampled", "--sample-size", "1"], "--sample-size", True),
    ("ray_scaling", ["--mode", "d0-sampled", "--objects", "10"], "--sample-size", True),
    ("theory_on_grasping", ["--seeds", "abc"], "--seeds", True),
    ("theory_on_grasping", ["--seeds", "1"], "--seeds", True),
    ("trial_checks", ["--poses", "abc"], "--poses", True),
    ("trial_checks", ["--threads", "0"], "--threads", True),
]


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(
        os.pathsep)
    return env


@pytest.mark.parametrize("script,argv,flag,light", CASES,
                         ids=[f"{s} {' '.join(a)}" for s, a, _, _ in CASES])
def test_bad_experiment_flag_is_one_line(script, argv, flag, light, tmp_path):
    work = tmp_path / "cwd"
    work.mkdir()
    out = tmp_path / "result.json"
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(out), f"experiments.{script}",
                           *argv], cwd=work, env=_env(), capture_output=True, text=True,
                          timeout=120, check=False)
    assert out.exists(), proc.stderr[-2000:]
    res = json.loads(out.read_text())
    lines = [line for line in res["err"].splitlines() if line.strip()]
    assert res["code"] == 2, res
    assert len(lines) == 1, res["err"]
    assert flag in lines[0] and "usage:" not in res["err"], lines
    assert lines[0].startswith(f"python -m experiments.{script}"), lines
    if light:
        assert res["heavy"] == [], res["heavy"]
    assert list(work.iterdir()) == []  # nothing written


def test_run_as_module_and_as_sern_experiment(tmp_path, capsys):
    """The line names the command as it was typed: ``python -m experiments.NAME`` run as a
    module, ``sern experiment NAME`` through the CLI; --help still prints the usage."""
    proc = subprocess.run([sys.executable, "-m", "experiments.hard_objects", "--poses", "x"],
                          cwd=tmp_path, env=_env(), capture_output=True, text=True,
                          timeout=120, check=False)
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        ("python -m experiments.hard_objects: error: argument --poses: expected an integer, "
         "got 'x' (see python -m experiments.hard_objects --help)")], proc.stderr
    from sern_jax.commands import main as cli

    with pytest.raises(SystemExit) as exc:  # argparse exits (the `sern` process with it)
        cli.main(["experiment", "trial_checks", "--poses", "0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [("sern experiment trial_checks: error: argument --poses: must be an integer "
                    ">= 1, "
                    "got 0 (see sern experiment trial_checks --help)")], err
    with pytest.raises(SystemExit) as exc:
        cli.main(["experiment", "grasp_learning", "--help"])
    assert exc.value.code == 0
    help_text = capsys.readouterr().out
    assert help_text.startswith("usage: sern experiment grasp_learning") and "--seeds" in help_text


def test_every_script_parser_is_the_shared_one():
    """No experiment script builds a plain ``argparse.ArgumentParser`` (its errors would be
    argparse's usage block): each uses ``validate.script_parser``."""
    plain, shared = [], []
    for path in sorted((ROOT / "experiments").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                name = ast.unparse(node.func)
                if name.endswith("ArgumentParser"):
                    plain.append(f"{path.name}:{node.lineno}")
                elif name.endswith("script_parser"):
                    shared.append(path.name)
    assert not plain, plain
    mains = {p.name for p in (ROOT / "experiments").glob("*.py")
             if "\ndef main(" in p.read_text()}
    assert mains and mains <= set(shared), sorted(mains - set(shared))
