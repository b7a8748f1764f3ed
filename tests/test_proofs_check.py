"""`sern check --quick` end to end, plus the harness self-test with deliberately wrong bounds.

The quick run is executed once per session in-process; its simulations are cached, so the
wrong-bound evaluations reuse the same data (the only thing that changes is the bound).
"""

import argparse
import json

import pytest

from sern_jax.commands import check as cli
from sern_jax.commands.scripts import script_module

# the modules `sern check` uses (sern_jax.proofs_check installed), so the cached runs are shared
framework = script_module("proofs_check", "framework")
registry = script_module("proofs_check", "registry")


def _args(tmp, **kw):
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    cli.add_parser(sub)
    argv = ["check", "--quick", "--out", str(tmp), "--no-figures"]
    for k, v in kw.items():
        flag = "--" + k.replace("_", "-")
        if v is True:
            argv.append(flag)
        elif isinstance(v, (list, tuple)):
            argv += [flag, *map(str, v)]
        else:
            argv += [flag, str(v)]
    return parser.parse_args(argv)


@pytest.fixture(scope="session")
def quick_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("check")
    out = tmp / "report.json"
    rc = cli.run(_args(tmp, name="quick", json_out=out))
    return rc, json.loads(out.read_text()), tmp / "quick"


def test_quick_all_verdicts_as_expected(quick_run):
    rc, doc, run_dir = quick_run
    names = [s["name"] for s in doc["summary"]]
    assert names == list(registry.NAMES)
    bad = [(s["name"], s["expected"], s["verdict"]) for s in doc["summary"] if not s["ok"]]
    assert bad == []
    assert rc == 0
    assert (run_dir / "report.md").exists() and (run_dir / "metadata.json").exists()
    # Both kinds of expectation are represented, and negative controls really FAIL.
    exp = {s["name"]: (s["expected"], s["verdict"]) for s in doc["summary"]}
    assert exp["t2_negative_control_8"] == ("FAILS", "FAIL")
    assert exp["t1_needs_clip"] == ("FAILS", "FAIL")
    assert exp["t2_exact_binomial"] == ("HOLDS", "PASS")


def test_every_check_fails_with_its_wrong_bound(quick_run):
    """Each check family can flip: HOLDS checks FAIL with the wrong bound; FAILS checks (whose
    wrong bound is a correct one) then no longer FAIL. Same cached data, only the bound changes."""
    ctx = framework.Context(quick=True, mutate=True)
    for check in registry.all_checks():
        res = framework.run_check(check, ctx)
        if check.expected == framework.HOLDS:
            assert res.verdict == framework.FAIL, (check.name, res.verdict, res.headline)
        else:
            assert res.verdict != framework.FAIL, (check.name, res.verdict, res.headline)
        assert not res.ok, check.name


def test_wrong_bounds_run_exits_nonzero(quick_run, tmp_path):
    # A negative control that passes means the harness is broken: the exit status says so.
    rc = cli.run(_args(tmp_path, only=["t2_negative_control_8", "t2_exact_binomial"],
                       wrong_bounds=True))
    assert rc == 1


def test_bad_input_is_rejected_before_running(tmp_path):
    with pytest.raises(ValueError, match="unknown check 'no_such_check'"):
        cli.run(_args(tmp_path, only=["no_such_check"]))
    with pytest.raises(ValueError, match="--seeds"):
        cli.run(_args(tmp_path, seeds=1))


def test_cells_and_verdict_logic():
    c_ok = framework.exact_cell("x", 1.0, 1.0 - 1e-12, "ge")
    c_bad = framework.exact_cell("y", 1.0, 1.0 + 1e-6, "ge")
    assert not c_ok.violated and c_bad.violated
    # A tail bound below 3/S has no power: UNINFORMATIVE, never PASS.
    cell = framework.tail_cell("t", 0, 100, 1e-4)
    assert framework.decide([cell], 0.01) == framework.UNINFORMATIVE
    # Vacuous cells alone give VACUOUS.
    v = framework.mean_cell("v", [1.0, 2.0, 3.0], 100.0, "le", vacuous=True)
    assert framework.decide([v], 0.01) == framework.VACUOUS
    # A clear mean violation is rejected after Holm.
    m = framework.mean_cell("m", [5.0, 5.1, 4.9, 5.2, 4.8] * 20, 0.0, "le")
    assert framework.decide([m, v], 0.01) == framework.FAIL


def test_figures_from_saved_results(quick_run):
    """figures/make_theory_figs draws from the saved figure_data.json alone."""
    make_theory_figs = script_module("figures", "make_theory_figs")

    _, _, run_dir = quick_run
    made = make_theory_figs.make_all(run_dir)
    names = {p.name for p in made}
    for expected in ("counts_vs_c.png", "tail_bounds.png", "regret_vs_bounds.png",
                     "ratio_vs_T_alpha0.png", "l1_loss_failure.png", "fixed_alpha.png"):
        assert expected in names
    assert any(n.startswith("tstar_heatmap") for n in names)
    assert all(p.stat().st_size > 10_000 for p in made)
