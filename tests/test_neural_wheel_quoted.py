"""The numbers docs/NEURAL.md quotes for the Neural-Linear Thompson learner on the wheel
bandit are recomputed from the committed per-seed files
(experiments/results/wheel_neural_lints*/d<δ>/results.npz: regret_rb [S, G] per policy, with
the command in config.json / metadata.json): one row per variant of the learner (σ² per arm
or pooled × prior mean network or zero) and the paired differences between variants."""

from pathlib import Path

import numpy as np
import pytest

from sern_jax.infra import io
from sern_jax.analysis import stats

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
DELTAS = ("0.5", "0.7", "0.9", "0.95", "0.99")
# variant: (folder, label in docs/NEURAL.md, nl_sigma2, nl_prior_mean)
VARIANTS = {
    "arm_network": ("wheel_neural_lints", "neural_lints (per-arm, 2026-11-24)", None, None),
    "arm_zero": ("wheel_neural_lints_arm_zero", "neural_lints, σ² per arm, prior mean zero",
                 "arm", "zero"),
    "pooled_zero": ("wheel_neural_lints_pooled_zero",
                    "neural_lints, σ² pooled, prior mean zero", "pooled", "zero"),
    "pooled_network": ("wheel_neural_lints_pooled_network",
                       "neural_lints, σ² pooled, prior mean network (default)", "pooled",
                       "network"),
}
# the paired comparisons quoted: (a, b) means a − b
PAIRS = (("pooled_network", "arm_network"), ("arm_zero", "arm_network"),
         ("pooled_zero", "pooled_network"))


def _ratio_interval(num, den, num_boot=2000, seed=0):
    """sern_jax/experiment/neural_regret.py's paired seed-bootstrap, restated."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, num.size, (num_boot, num.size))
    boots = num[idx].mean(1) / den[idx].mean(1)
    return num.mean() / den.mean(), np.percentile(boots, 2.5), np.percentile(boots, 97.5)


def _regret(variant, delta, policy="neural_lints"):
    res = io.load_npz(RESULTS / VARIANTS[variant][0] / f"d{delta}" / "results.npz")
    return res[f"{policy}__regret_rb"][:, -1].astype(np.float64)


def row(variant):
    cells = []
    for d in DELTAS:
        r, lo, hi = _ratio_interval(_regret(variant, d), _regret(variant, d, "uniform"))
        cells.append(f"{r:.3f} [{lo:.3f}, {hi:.3f}]")
    return f"| {VARIANTS[variant][1]} | " + " | ".join(cells) + " |"


def pair_row(a, b):
    """a − b per δ as a fraction of Uniform's R_T: Student-t 95% over seeds, Holm over δ."""
    diffs = stats.paired_differences([_regret(a, d) for d in DELTAS],
                                     [_regret(b, d) for d in DELTAS], names=DELTAS)
    cells = []
    for d, r in zip(DELTAS, diffs):
        u = _regret(a, d, "uniform").mean()
        cells.append(f"{r.mean / u:+.3f} [{r.lower / u:+.3f}, {r.upper / u:+.3f}] "
                     f"{'(resolved)' if r.resolved else '(not resolved)'}")
    return f"| {a} − {b} | " + " | ".join(cells) + " |"


def test_configs_are_the_quoted_command():
    for variant, (folder, _, sigma2, prior) in VARIANTS.items():
        for d in DELTAS:
            cfg = io.load_json(RESULTS / folder / f"d{d}" / "config.json")["experiment"]
            assert float(cfg["delta"]) == float(d) and cfg["num_seeds"] == 20
            assert cfg["horizon"] == 1000 and cfg["seed"] == 0 and cfg["hidden"] == [50]
            assert cfg["update_every"] == 50 and cfg["fit_steps"] == 20
            assert cfg.get("nl_sigma2") == sigma2 and cfg.get("nl_prior_mean") == prior, variant
            # Uniform's seeds are the same in every variant (common random numbers)
            np.testing.assert_array_equal(_regret(variant, d, "uniform"),
                                          _regret("arm_network", d, "uniform"))


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_quoted_rows_match_the_per_seed_files(variant):
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())  # reflow-proof
    assert row(variant) in doc, row(variant)
    for d in DELTAS:
        summary = io.load_json(RESULTS / VARIANTS[variant][0] / f"d{d}" / "summary.json")
        r = summary["normalised_by_uniform"]["neural_lints"]["ratio"]
        assert r == pytest.approx(_regret(variant, d).mean() / _regret(variant, d,
                                                                       "uniform").mean())


def test_quoted_paired_differences_and_uniform_regret():
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    for a, b in PAIRS:
        assert pair_row(a, b) in doc, pair_row(a, b)
    uniform = [f"{_regret('arm_network', d, 'uniform').mean():,.0f}" for d in DELTAS]
    assert f"Uniform's R_T on these seeds: {', '.join(uniform)}" in doc


def test_quoted_prior_dominance_arithmetic():
    """The σ² lower bounds quoted beside the per-arm/pooled comparison: arm 4's mean pull
    count at δ = 0.5 (σ² per arm, prior mean network), b0/(a0 + n/2 − 1) and its sd, and the
    pooled bound over the 1,000 rows (a0 = b0 = 6, the learner's defaults)."""
    from sern_jax.learners import neural_linear as nl

    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    cfg = nl.NeuralLinTSConfig()
    a0, b0 = cfg.a0, cfg.b0
    counts = io.load_npz(RESULTS / "wheel_neural_lints" / "d0.5" / "results.npz")[
        "neural_lints__counts"][:, -1]
    n4 = counts[:, 4].mean()
    bound = b0 / (a0 + n4 / 2 - 1)
    for q in (f"an arm with {n4:.1f} rows", f"keeps E σ² ≥ {bound:.2f}",
              f"sd ≥ {np.sqrt(bound):.2f} on rewards",
              f"over 1,000 rows has E σ² ≥ {b0 / (a0 + 1000 / 2 - 1):.3f}"):
        assert q in doc, q


SEED1 = RESULTS / "wheel_neural_lints_seed1"


def _seed1(variant, delta, policy="neural_lints"):
    res = io.load_npz(SEED1 / variant / f"d{delta}" / "results.npz")
    return res[f"{policy}__regret_rb"][:, -1].astype(np.float64)


def test_quoted_replication_on_fresh_seeds():
    """The 50-seed replication (root seed 1, one --deltas sweep per variant): ratios, the
    paired differences (Student t 95%, Holm over δ) and the per-δ wall seconds that show one
    compilation per sweep, recomputed from the committed run directories."""
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    quoted = []
    for v in ("pooled", "arm"):
        for d in DELTAS:
            cfg = io.load_json(SEED1 / v / f"d{d}" / "config.json")["experiment"]
            assert cfg["num_seeds"] == 50 and cfg["seed"] == 1 and cfg["nl_sigma2"] == v
            assert cfg["nl_prior_mean"] == "network"
        ratios = [_seed1(v, d).mean() / _seed1(v, d, "uniform").mean() for d in DELTAS]
        quoted.append(" / ".join(f"{r:.3f}" for r in ratios))
    diffs = stats.paired_differences([_seed1("pooled", d) for d in DELTAS],
                                     [_seed1("arm", d) for d in DELTAS], names=DELTAS)
    cells = []
    for d, r in zip(DELTAS, diffs):
        u = _seed1("pooled", d, "uniform").mean()
        cells.append(f"{r.mean / u:+.3f} [{r.lower / u:+.3f}, {r.upper / u:+.3f}]")
    quoted.append("; ".join(cells))
    quoted.append(f"resolved at {sum(r.resolved for r in diffs)} of the 5")
    walls = {v: [io.load_json(SEED1 / v / f"d{d}" / "metadata.json")[
        "wall_seconds_per_policy"]["neural_lints"] for d in DELTAS] for v in ("pooled", "arm")}
    for v in ("pooled", "arm"):
        w = walls[v]
        assert max(w[1:]) < w[0] / 10  # the first δ compiles, the others reuse it
        quoted.append(f"{v}: {w[0]:.1f} s for δ = 0.5, then {min(w[1:]):.1f}–{max(w[1:]):.1f} s")
    for q in quoted:
        assert q in doc, q


BASE = RESULTS / "wheel_sern_egreedy_greedy"
BASE_POLICIES = ("sern", "egreedy", "greedy")


def _base(delta, policy):
    res = io.load_npz(BASE / f"d{delta}" / "results.npz")
    return res[f"{policy}__regret_rb"][:, -1].astype(np.float64)


def _base_interval(policy, d):
    return _ratio_interval(_base(d, policy), _base(d, "uniform"))


def test_quoted_sern_egreedy_greedy_rows_and_rankings():
    """The sern / egreedy / greedy rows (one --deltas sweep on the same 20 seeds as the
    Neural-Linear runs: Uniform's regret identical) and the ranking sentences built on them."""
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    for d in DELTAS:
        cfg = io.load_json(BASE / f"d{d}" / "config.json")["experiment"]
        assert float(cfg["delta"]) == float(d) and cfg["num_seeds"] == 20 and cfg["seed"] == 0
        assert cfg["horizon"] == 1000 and cfg["hidden"] == [50] and cfg["update_every"] == 50
        assert cfg["fit_steps"] == 20 and cfg["batch_size"] == 64 and cfg["alpha0"] == 0.1
        assert tuple(cfg["policies"]) == BASE_POLICIES + ("uniform",)
        np.testing.assert_array_equal(_base(d, "uniform"), _regret("arm_network", d, "uniform"))
    for policy in BASE_POLICIES:
        cells = [f"{r:.3f} [{lo:.3f}, {hi:.3f}]"
                 for r, lo, hi in (_base_interval(policy, d) for d in DELTAS)]
        line = f"| {policy} | " + " | ".join(cells) + " |"
        assert line in doc, line
    nl = {d: _ratio_interval(_regret("pooled_network", d), _regret("pooled_network", d,
                                                                    "uniform")) for d in DELTAS}
    base = {(p, d): _base_interval(p, d) for p in BASE_POLICIES for d in DELTAS}
    # lowest of the four at δ ≤ 0.9, its interval below the three others'
    for d in DELTAS[:3]:
        assert all(nl[d][2] < base[p, d][1] for p in BASE_POLICIES), d
    # at δ = 0.95 its interval overlaps ε-greedy's and greedy's
    for p in ("egreedy", "greedy"):
        assert nl["0.95"][2] > base[p, "0.95"][1] and base[p, "0.95"][2] > nl["0.95"][1]
    # SERN second of the four at δ ≤ 0.7
    for d in DELTAS[:2]:
        order = sorted([("neural_lints", nl[d][0])] + [(p, base[p, d][0]) for p in
                                                      BASE_POLICIES], key=lambda x: x[1])
        assert order[1][0] == "sern", (d, order)
    # SERN behind ε-greedy and greedy at δ ≥ 0.95, intervals apart
    for d in DELTAS[3:]:
        assert all(base["sern", d][1] > base[p, d][2] for p in ("egreedy", "greedy")), d
    quoted = ["lowest ratio of the four methods at δ ≤ 0.9 ("
              + " / ".join(f"{nl[d][0]:.3f}" for d in DELTAS[:3]) + ";",
              f"({nl['0.95'][0]:.3f} against {base['egreedy', '0.95'][0]:.3f} and "
              f"{base['greedy', '0.95'][0]:.3f})"]
    for q in quoted:
        assert q in doc, q


def test_pooling_resolved_at_four():
    doc = " ".join((ROOT / "docs" / "NEURAL.md").read_text().split())
    a, b = "pooled_network", "arm_network"
    diffs = stats.paired_differences([_regret(a, d) for d in DELTAS],
                                     [_regret(b, d) for d in DELTAS], names=DELTAS)
    u = [_regret(a, d, "uniform").mean() for d in DELTAS]
    means = [r.mean / uu for r, uu in zip(diffs, u)]
    assert all(m < 0 for m in means) and sum(r.resolved for r in diffs) == 4
    assert not diffs[-1].resolved
    last = diffs[-1]
    q = (f"by {-max(means):.3f}–{-min(means):.3f} in point estimate at every δ, resolved at "
         f"four (not at δ = 0.99: {last.mean / u[-1]:+.3f} [{last.lower / u[-1]:+.3f}, "
         f"{last.upper / u[-1]:+.3f}])").replace("-0", "−0")
    assert q in doc, q
