"""The committed `sern check` reports and wheel-bandit runs are what they say they are: a full
run with every verdict as expected, Student-t mean cells, p-values consistent with the cells'
n and se, and run configurations with common random numbers across the wheel folders."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from sern_jax.analysis import stats
from sern_jax.infra import io

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
REPORT = RESULTS / "theory" / "check_full.json"
A3 = RESULTS / "theory_neural" / "check_n1_a3_full.json"
DELTAS = ("0.5", "0.7", "0.9", "0.95", "0.99")


def _ends(cell):
    """A mean or equality cell's stored interval, checked to be Student t (n − 1 dof) from its
    n and se: the end facing the bound one-sided 99 %, the other two-sided 99 % (both
    two-sided for an equality cell)."""
    m, se, df = cell["statistic"], cell["se"], cell["n"] - 1
    one, two = sps.t.ppf(0.99, df) * se, sps.t.ppf(0.995, df) * se
    want = {"le": (m - one, m + two), "ge": (m - two, m + one), "eq": (m - two, m + two)}
    lo, hi = want[cell["direction"]]
    assert cell["lower"] == pytest.approx(lo, rel=1e-12, abs=1e-12), cell["label"]
    assert cell["upper"] == pytest.approx(hi, rel=1e-12, abs=1e-12), cell["label"]


def test_the_report_is_a_full_run_with_every_verdict_as_expected():
    doc = json.loads(REPORT.read_text())
    opts = doc["options"]
    assert not opts["quick"] and not opts["wrong_bounds"] and opts["seeds"] is None
    assert opts["only"] in (None, []) and opts["alpha"] == 0.01
    assert doc["all_as_expected"] and all(c["ok"] for c in doc["checks"])
    mean_cells = [c for ch in doc["checks"] for c in ch["cells"] if c.get("n", 0) >= 2
                  and c["se"] > 0 and "zero-variance" not in c["note"]]
    assert len(mean_cells) > 100
    for c in mean_cells:
        _ends(c)


def test_a3_report_pvalues_follow_from_each_cells_n_and_se():
    doc = json.loads(A3.read_text())
    (a3,) = [c for c in doc["checks"] if c["name"] == "a3_neural_error"]
    alpha = doc["options"]["alpha"]
    for c in a3["cells"]:
        n, se = c["n"], c["se"]
        assert n == a3["seeds"] and se > 0, c["label"]
        t = (c["statistic"] - c["bound"]) / se
        assert c["pvalue"] == pytest.approx(sps.t.sf(t, n - 1), rel=1e-9), c["label"]
        assert c["detectable"] == pytest.approx(
            c["bound"] + stats.t_detectable_excess(se, n, alpha), rel=1e-9), c["label"]


def _regret(folder, delta, policy):
    res = io.load_npz(RESULTS / folder / f"d{delta}" / "results.npz")
    return res[f"{policy}__regret_rb"][:, -1].astype(np.float64)


@pytest.mark.parametrize("folder", ["wheel_sern_egreedy_greedy", "wheel_neural_lints",
                                    "wheel_neural_lints_arm_zero",
                                    "wheel_neural_lints_pooled_zero",
                                    "wheel_neural_lints_pooled_network"])
def test_wheel_runs_share_their_seeds_and_settings(folder):
    """Every wheel folder ran the same 20 seeds (Uniform's regret equal in all of them: common
    random numbers), and each summary's ratio is what its per-seed file gives."""
    for d in DELTAS:
        cfg = io.load_json(RESULTS / folder / f"d{d}" / "config.json")["experiment"]
        assert float(cfg["delta"]) == float(d) and cfg["num_seeds"] == 20 and cfg["seed"] == 0
        assert cfg["horizon"] == 1000 and cfg["hidden"] == [50] and cfg["update_every"] == 50
        np.testing.assert_array_equal(_regret(folder, d, "uniform"),
                                      _regret("wheel_neural_lints", d, "uniform"))
        summary = io.load_json(RESULTS / folder / f"d{d}" / "summary.json")
        for pol, rec in summary["normalised_by_uniform"].items():
            assert rec["ratio"] == pytest.approx(
                _regret(folder, d, pol).mean() / _regret(folder, d, "uniform").mean()), pol
