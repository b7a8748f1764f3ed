"""Exact fast Thompson sampling (issue 20): the Beta sampler against scipy's Beta (KS, with a
wrong-parameter control that must fail), the batched runner against the general one."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats as st

from sern_jax.engine import drive as executor, fast_thompson
from sern_jax.core import prng, problems
from sern_jax.engine import simulate as sim

N = 20_000  # draws per parameter pair


def _draws(a, b, seed=0):
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(seed), i))(jnp.arange(10))
    fn = jax.jit(jax.vmap(lambda k: prng.sample_beta(k, jnp.full(N // 10, a, jnp.float32),
                                                     jnp.full(N // 10, b, jnp.float32))))
    return np.asarray(fn(keys), np.float64).ravel()


# order statistics (min(a, b) = 1 or 2, also with a real other parameter; with a large one
# most draws take the expm1 polynomial), and Cheng's BB (min > 2, or between 1 and 2),
# symmetric, skewed and large
PAIRS = [(1.0, 1.0), (1.0, 9.0), (6.0, 1.0), (1.0, 3000.0), (2000.0, 1.0), (2.0, 2.0),
         (2.0, 160.0), (9.0, 2.0), (2.0, 7.5), (1500.0, 2.0), (1.5, 4.0), (3.0, 3.0),
         (35.0, 4.0), (300.0, 700.0)]


@pytest.mark.parametrize("a,b", PAIRS)
def test_beta_draws_match_scipy_and_a_wrong_parameter_fails(a, b):
    x = _draws(a, b)
    # Beta's support in float32 is [0, 1]: a draw within half an ulp of 1 rounds to 1.0 (the
    # H100's exp does so for Beta(2000, 1); about 2000 * 2^-25 of the true draws lie there),
    # so the ends are allowed, but only as often as that rounding explains
    assert np.all((x >= 0) & (x <= 1))
    near = max(a, b) * 2.0 ** -24  # generous: the mass within one ulp of either end
    assert np.mean((x == 0) | (x == 1)) <= 10 * near + 3 / x.size
    assert st.kstest(x, st.beta(a, b).cdf).pvalue > 1e-3
    # control: a 10% larger first parameter is detected by the same test on the same draws
    assert st.kstest(x, st.beta(a * 1.1, b).cdf).pvalue < 1e-3


@pytest.mark.parametrize("a,b", [(1.0, 3000.0), (2.0, 500.0), (5.0, 9.0)])
def test_float64_beta_draws_match_scipy(a, b):
    """In float64 the order-statistics forms use jnp.expm1 (the float32 Taylor branch would
    carry ~1e-9 relative error): KS against scipy with the wrong-parameter control."""
    with jax.enable_x64():
        keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(3), i))(jnp.arange(10))
        x = np.asarray(jax.jit(jax.vmap(lambda k: prng.sample_beta(
            k, jnp.full(N // 10, a, jnp.float64), jnp.full(N // 10, b, jnp.float64))))(keys))
    assert x.dtype == np.float64 and np.all((x > 0) & (x < 1))
    assert st.kstest(x.ravel(), st.beta(a, b).cdf).pvalue > 1e-3
    assert st.kstest(x.ravel(), st.beta(a * 1.1, b).cdf).pvalue < 1e-3


def test_beta_below_one_is_nan_not_a_wrong_draw():
    x = jax.jit(prng.sample_beta)(jax.random.key(0), jnp.array([0.5, 2.0]),
                                  jnp.array([2.0, 0.9]))
    assert np.all(np.isnan(np.asarray(x)))


CFG = sim.RunConfig(policy="thompson", num_arms=8, horizon=300, num_checkpoints=8,
                    random_means=True)
PARAMS = sim.default_params(CFG, problems.bernoulli([0.5] * 8))


def test_fast_thompson_equals_the_general_runner():
    assert executor.plan_run(CFG, PARAMS, 40).fast
    fast = executor.run_seeds(CFG, PARAMS, seed=1, num_seeds=40, runner="fast")
    general = executor.run_seeds(CFG, PARAMS, seed=1, num_seeds=40, runner="general")
    # same draws lane by lane: the same arms, the same Kahan-summed regret
    np.testing.assert_array_equal(fast.counts, general.counts)
    for field in ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "compensator",
                  "min_prob"):
        np.testing.assert_allclose(getattr(fast, field), getattr(general, field), rtol=1e-6,
                                   atol=1e-6, err_msg=field)
    # seeds differ from each other, and Thompson learns: the best arm is pulled most
    assert len({tuple(c) for c in fast.counts[:, -1]}) == 40
    assert fast.counts[:, -1].sum(-1).tolist() == [300] * 40


@pytest.mark.parametrize("lookahead,pulled_tries", [(1, 0), (3, 1), (4, 3)])
def test_fast_thompson_lookahead_keeps_the_draws(lookahead, pulled_tries):
    """Drawing ahead (any depth, any number of immediate tries for the pulled lane) changes
    only the loop, not the draws: the same arms as the general runner, seed by seed."""
    general = executor.run_seeds(CFG, PARAMS, seed=2, num_seeds=16, runner="general")
    fn = jax.jit(fast_thompson.make_batched(CFG, lookahead=lookahead,
                                            pulled_tries=pulled_tries, with_steps=True))
    out, steps = fn(sim.seed_keys(jax.random.key(2), 16), PARAMS)
    np.testing.assert_array_equal(np.asarray(out.counts), general.counts)
    # every round costs at least one loop step, and rejections cost a few more
    assert CFG.horizon <= int(np.max(steps)) < 4 * CFG.horizon
    with pytest.raises(ValueError, match="lookahead"):
        fast_thompson.make_batched(CFG, lookahead=0)


def test_hold_is_the_identity_on_every_uniform_and_key_word():
    """prng.hold / hold_bits only stop XLA from recomputing a hash in every fusion; they must
    return their argument bit for bit: all 2^23 float32 uniforms of open_unit, 0 and 1, and
    key words with every 16-bit half."""
    m = np.arange(2**23, dtype=np.float32)
    u = np.concatenate([(m + np.float32(0.5)) * np.float32(2.0**-23), [0.0, 1.0]]).astype(
        np.float32)
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold)(jnp.asarray(u))), u)
    half = np.arange(2**16, dtype=np.uint32)
    words = np.concatenate([half, half << np.uint32(16), (half << np.uint32(16)) | half[::-1]])
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold_bits)(jnp.asarray(words))),
                                  words)


def test_packed_try_is_the_try_held_exactly():
    """beta_try_packed is beta_try's draw where accepted and REJECTED elsewhere, bit for bit
    (prng.hold is exact on every value a draw can take: all float32 from 2^-60 to 1, sampled,
    and REJECTED), so the fast runner's held values are the general runner's draws."""
    rng = np.random.default_rng(0)
    bits = rng.integers(np.float32(2.0**-60).view(np.uint32), np.float32(1.0).view(np.uint32),
                        2**22, dtype=np.uint32, endpoint=True)
    x = np.concatenate([bits.view(np.float32), [1.0, prng.REJECTED]]).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(jax.jit(prng.hold)(jnp.asarray(x))), x)
    a = jnp.asarray(rng.integers(1, 40, (64, 64)), jnp.float32)
    b = jnp.asarray(rng.integers(1, 400, (64, 64)), jnp.float32)
    lane = jnp.arange(64, dtype=jnp.uint32)[None, :]
    tries = jnp.asarray(rng.integers(0, 3, (64, 64)), jnp.uint32)
    k1, k2 = jnp.uint32(12345), jnp.uint32(678)
    theta, acc = jax.jit(prng.beta_try)(k1, k2, a, b, tries, lane)
    packed = jax.jit(prng.beta_try_packed)(k1, k2, a, b, tries, lane)
    assert 0.7 < float(jnp.mean(acc)) < 1.0  # some rejections, or the test is hollow
    np.testing.assert_array_equal(np.asarray(packed),
                                  np.where(np.asarray(acc), np.asarray(theta), prng.REJECTED))


def test_fast_thompson_refuses_what_it_does_not_reproduce():
    for bad in (dataclasses.replace(CFG, policy="softmax"),
                dataclasses.replace(CFG, diagnostics=True),
                dataclasses.replace(CFG, num_contexts=2)):
        assert not fast_thompson.supports(bad)
    with pytest.raises(ValueError, match="fast_thompson supports"):
        fast_thompson.make_batched(dataclasses.replace(CFG, diagnostics=True))


def test_readme_quotes_the_committed_lookahead_and_h100_bench_files():
    """The README's figures for the lookahead loop (2 cores), the H100 Thompson runners and
    the 5-repeat H100 softmax public path are recomputed from the committed bench JSONs."""
    import json
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    bench = root / "experiments/results/bench"

    def load(name):
        return json.loads((bench / name).read_text())

    runs = [load(f"bandit_thompson_2core_lookahead_{i}.json") for i in (1, 2, 3)]
    assert [r["device"]["num_devices"] for r in runs] == [1, 2, 1]
    assert all(r["workload"]["policy"] == "thompson" and r["workload"]["horizon"] == 2000
               and r["workload"]["seeds"] == 1024 and r["numpy_seeds"] == 256 for r in runs)
    loads = [x for r in runs for x in (r["machine"]["loadavg_before"][0],
                                       r["machine"]["loadavg_after"][0])]
    h100 = load("bandit_thompson_h100_public.json")
    # the quoted H100 run draws the documented streams: the fast runner's arms are the
    # general runner's on every seed (the earlier build that held on the GPU: on none)
    assert h100["regret_agreement"]["fast_general_counts_identical_fraction"] == 1.0
    assert load("bandit_thompson_h100_lookahead.json")["regret_agreement"][
        "fast_general_counts_identical_fraction"] == 0.0
    soft = load("bandit_softmax_h100_r5.json")
    assert h100["device"]["backend"] == soft["device"]["backend"] == "gpu"
    assert soft["workload"]["seeds"] == 200_000 and len(soft["naive_jax"]["times_s"]) == 5
    paired = [n / s for n, s in zip(soft["naive_jax"]["times_s"],
                                    soft["run_seeds_summary"]["times_s"])]
    text = " ".join((root / "README.md").read_text().split())
    for quoted in (
            f"(one device, two, one; load {min(loads):.1f}–{max(loads):.1f}): best path "
            + ", ".join(f"{r['seed_rounds_per_s'] / 1e6:.2f}M" for r in runs[:2])
            + f" and {runs[2]['seed_rounds_per_s'] / 1e6:.2f}M seed-rounds/s, "
            + ", ".join(f"{r['speedup_vs_numpy']:.1f}×" for r in runs[:2])
            + f" and {runs[2]['speedup_vs_numpy']:.1f}× NumPy in the same process "
            f"({runs[0]['numpy_seed_rounds_per_s'] / 1e6:.2f}M)",
            (f"the fast runner now draws {h100['fast_seed_rounds_per_s'] / 1e6:.0f}M "
             f"seed-rounds/s against the general runner's "
             f"{h100['general_seed_rounds_per_s'] / 1e6:.1f}M"),
            f"`run_seeds(summary=True)` {h100['run_seeds_summary_seed_rounds_per_s'] / 1e6:.0f}M",
            (f"per-seed arrays {soft['run_seeds_seed_rounds_per_s'] / 1e9:.2f}G; "
             f"**`run_seeds(summary=True)` "
             f"{soft['run_seeds_summary_seed_rounds_per_s'] / 1e9:.2f}G** "
             f"({soft['public_over_fast']:.2f}× the engine, "
             f"{soft['public_over_naive_jax']:.2f}× the naive peer at "
             f"{soft['naive_jax_seed_rounds_per_s'] / 1e9:.2f}G; "
             f"{min(paired):.3f}–{max(paired):.3f}× run by run, so short of the 1.3× goal) | "
             f"{soft['fast_seed_rounds_per_s'] / 1e9:.2f}G")):
        assert quoted in text, quoted
    # the NumPy reference ran at the same speed in all three (the figure quoted once)
    assert len({f"{r['numpy_seed_rounds_per_s'] / 1e6:.2f}" for r in runs}) == 1
    assert max(paired) < 1.3  # the sentence "short of the 1.3× goal" holds run by run


def test_readme_quotes_the_split_summary_h100_bench():
    """The README's row for the summary path after the engine/reduction split is recomputed
    from the committed 5-run H100 JSON, and the 1.3x claim holds in the runs it names."""
    import json
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    soft = json.loads((root / "experiments/results/bench/bandit_softmax_h100_r5_split.json")
                      .read_text())
    assert soft["device"]["backend"] == "gpu" and soft["workload"]["seeds"] == 200_000
    assert len(soft["naive_jax"]["times_s"]) == len(soft["run_seeds_summary"]["times_s"]) == 5
    paired = [n / s for n, s in zip(soft["naive_jax"]["times_s"],
                                    soft["run_seeds_summary"]["times_s"])]
    text = " ".join((root / "README.md").read_text().split())
    quoted = (f"per-seed arrays {soft['run_seeds_seed_rounds_per_s'] / 1e9:.2f}G; "
              f"**`run_seeds(summary=True)` "
              f"{soft['run_seeds_summary_seed_rounds_per_s'] / 1e9:.2f}G** "
              f"({soft['public_over_fast']:.2f}× the engine, "
              f"{soft['public_over_naive_jax']:.2f}× the naive peer at "
              f"{soft['naive_jax_seed_rounds_per_s'] / 1e9:.2f}G; timed runs 2–5 "
              f"{min(paired[1:]):.3f}–{max(paired[1:]):.3f}×, the first {paired[0]:.3f}×: "
              f"it compiled the jitted seed-key call) | "
              f"{soft['fast_seed_rounds_per_s'] / 1e9:.2f}G")
    assert quoted in text, quoted
    assert soft["public_over_naive_jax"] >= 1.3 and min(paired[1:]) >= 1.3
    assert soft["public_over_fast"] >= 0.95
    assert soft["regret_agreement"]["summary_counts_min_equal_fast"]


def test_readme_quotes_the_8b9124f_bench_files():
    """The README's figures for the one-pass, rejection-free-at-2 code (8b9124f) are recomputed
    from the committed bench JSONs (one quiet run, three under load) and the one-core record;
    the quiet run meets the issue's goal, the loaded ones do not, as the README says."""
    import json
    import pathlib
    import re

    root = pathlib.Path(__file__).resolve().parents[1]
    bench = root / "experiments/results/bench"
    runs = [json.loads((bench / f"bandit_thompson_2core_8b9124f_{i}.json").read_text())
            for i in (1, 2, 3, 4)]
    for r in runs:
        w = r["workload"]
        assert (w["policy"], w["num_arms"], w["horizon"], w["seeds"], r["numpy_seeds"]) == (
            "thompson", 64, 2000, 1024, 256)
        assert r["regret_agreement"]["run_seeds_counts_equal_fast"]
    assert len({r["regret_agreement"]["fast_mean_regret_T"] for r in runs}) == 1  # same draws
    quiet, loaded = runs[0], runs[1:]

    def loads(rs):
        xs = [x for r in rs for x in (r["machine"]["loadavg_before"][0],
                                      r["machine"]["loadavg_after"][0])]
        return f"{min(xs):.1f}–{max(xs):.1f}"

    rs, npy = quiet["run_seeds_seed_rounds_per_s"], quiet["numpy_seed_rounds_per_s"]
    assert rs >= 1e6 and rs / npy >= 5 and quiet["best_path"] == "run_seeds"
    assert all(r["speedup_vs_numpy"] < 5 for r in loaded)
    numpy = [r["numpy_seed_rounds_per_s"] for r in loaded]
    text = " ".join((root / "README.md").read_text().split())
    paired = (bench / "bandit_thompson_1core_paired.txt").read_text()
    head, old = re.findall(r"([0-9.]+)M per CPU-second", paired)
    for quoted in (
            (f"17:59 UTC at load {loads([quiet])}: `run_seeds` {rs / 1e6:.2f}M seed-rounds/s, "
             f"{rs / npy:.1f}× NumPy's {npy / 1e6:.2f}M in the same process"),
            f"at load {loads(loaded)} (other engineers' jobs): best path "
            + ", ".join(f"{r['seed_rounds_per_s'] / 1e6:.2f}M" for r in loaded[:2])
            + f" and {loaded[2]['seed_rounds_per_s'] / 1e6:.2f}M, "
            + ", ".join(f"{r['speedup_vs_numpy']:.1f}×" for r in loaded[:2])
            + f" and {loaded[2]['speedup_vs_numpy']:.1f}× NumPy "
            f"({min(numpy) / 1e6:.2f}–{max(numpy) / 1e6:.2f}M)",
            f"{float(head):.2f}M seed-rounds per CPU-second against {float(old):.2f}M"):
        assert quoted in text, quoted
    assert "16e89b0" in paired and "steps/round 1.321" in paired
    fifth = json.loads((bench / "bandit_thompson_2core_8b9124f_5.json").read_text())
    assert fifth["workload"] == quiet["workload"] and fifth["speedup_vs_numpy"] < 5
    assert (fifth["regret_agreement"]["fast_mean_regret_T"]
            == quiet["regret_agreement"]["fast_mean_regret_T"])  # the same draws
    quoted = (f"a fifth at 18:37 UTC at load {loads([fifth])} (code of c3a17ac, float32 path "
              f"unchanged): best path {fifth['seed_rounds_per_s'] / 1e6:.2f}M, "
              f"{fifth['speedup_vs_numpy']:.1f}× NumPy's "
              f"{fifth['numpy_seed_rounds_per_s'] / 1e6:.2f}M")
    assert quoted in text, quoted


def test_readme_quotes_the_lead_idle_thompson_runs():
    """The lead's three idle re-runs at 5c1a869: every figure of the README's lead sentence is
    recomputed from the committed records, and each run meets the goal (>= 1M, >= 5x NumPy in
    the same process) on the best path and on run_seeds with per-seed arrays."""
    import json
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    bench = root / "experiments/results/bench"
    recs = [json.loads((bench / f"bandit_thompson_2core_idle_5c1a869_{i}.json").read_text())
            for i in (1, 2, 3)]
    runs = [r["bench"] for r in recs]
    for rec, r in zip(recs, runs):
        assert rec["commit"] == "5c1a869" and "--policy thompson" in rec["command"]
        w = r["workload"]
        assert (w["policy"], w["num_arms"], w["horizon"], w["seeds"], r["numpy_seeds"]) == (
            "thompson", 64, 2000, 1024, 256)
        npy = r["numpy_seed_rounds_per_s"]
        for rate in (r["seed_rounds_per_s"], r["run_seeds_seed_rounds_per_s"]):
            assert rate >= 1e6 and rate / npy >= 5
    text = " ".join((root / "README.md").read_text().split())

    def m(xs):
        return ", ".join(f"{x / 1e6:.2f}M" for x in xs[:2]) + f" and {xs[2] / 1e6:.2f}M"

    def x(xs):
        return ", ".join(f"{v:.1f}×" for v in xs[:2]) + f" and {xs[2]:.1f}×"

    best = [r["seed_rounds_per_s"] for r in runs]
    npy = [r["numpy_seed_rounds_per_s"] for r in runs]
    per_seed = [r["run_seeds_seed_rounds_per_s"] for r in runs]
    quoted = (f"best path {m(best)} seed-rounds/s, {x([b / n for b, n in zip(best, npy)])} "
              f"NumPy's {m(npy)} in the same process; `run_seeds` with per-seed arrays "
              f"{m(per_seed)} (" + ", ".join(f"{p / n:.1f}×" for p, n in zip(per_seed, npy))
              + ")")
    assert quoted in text, quoted
    slow = min(per_seed) / 0.25e6
    assert f"slowest `run_seeds` run would be {slow:.1f}×" in text
    assert f"the slowest best path {min(best) / 0.25e6:.1f}×" in text


def test_expm1_is_exact_enough_in_float64_and_float32():
    """prng._expm1: in float64 it must be jnp.expm1 (the float32 Taylor branch truncates at
    ~1e-9 relative, which the KS tests cannot see); in float32 within its documented error."""
    y64 = np.concatenate([-np.logspace(-12, 1, 200), np.logspace(-12, -1.3, 50)])
    with jax.enable_x64():
        y = jnp.asarray(y64, jnp.float64)
        got = np.asarray(prng._expm1(y, jnp.exp(y)))
    assert got.dtype == np.float64 and np.max(np.abs(got / np.expm1(y64) - 1)) < 1e-14
    y32 = y64.astype(np.float32)
    got = np.asarray(prng._expm1(jnp.asarray(y32), jnp.exp(jnp.asarray(y32))), np.float64)
    assert np.max(np.abs(got / np.expm1(y32.astype(np.float64)) - 1)) < 2e-6
