"""Tests for sern_jax.grasp.online (Algorithm 1 for grasping): a tiny end-to-end run,
resume after an interrupt, common random numbers, SERN's choice law, learning from
failures, and bad input refused before anything compiles."""

import shutil
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from sern_jax import io
from sern_jax.commands import main as cli
from sern_jax.grasp import artifacts, context, objects, online

# 1 object x 3 policies x 2 seeds x 2 rounds of 3 exploration + 2 evaluation grasps.
# ε = 0 makes egreedy the greedy policy: with common random numbers its row must equal
# greedy's exactly. A large learning rate makes 4 fit steps visible.
CONFIG = online.OnlineConfig(
    policies=("sern", "egreedy", "greedy"), num_seeds=2, rounds=2, explore=3, evaluate=2,
    epsilon=0.0, eval_poses=1, eval_trials=2, fit_steps=4, batch_size=8,
    learning_rate=1e-2)
OBJECT = "triangular_prism"


def _quiet(*_):
    pass


@pytest.fixture(scope="module")
def spec():
    return objects.make_object(OBJECT)


@pytest.fixture(scope="module")
def run_a(tiny_theta0, spec, tmp_path_factory):
    """An uninterrupted run; the checkpoint after round 1 is copied aside."""
    out = tmp_path_factory.mktemp("learn_a")
    aside = tmp_path_factory.mktemp("aside") / "checkpoint_round1.npz"
    real = online._save

    def save_and_copy(path, *args):
        real(path, *args)
        if args[-1] == 2:  # next_round = 2: round 1 finished
            shutil.copy(path, aside)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(online, "_save", save_and_copy)
        res = online.run(CONFIG, [spec], out, theta0=tiny_theta0, progress=False, log=_quiet)
    assert aside.exists()
    return res, out, aside


def test_tiny_run_table(run_a):
    res, out, _ = run_a
    table = res["table"]
    assert [(r["object"], r["policy"]) for r in table] == [
        (OBJECT, p) for p in CONFIG.policies]
    for r in table:
        assert len(r["rounds"]) == len(r["std"]) == CONFIG.rounds
        assert len(r["lowvar_rounds"]) == CONFIG.rounds + 1
        values = [r["theta0"], r["max"], *r["rounds"], *r["lowvar_rounds"]]
        assert all(0.0 <= v <= 100.0 for v in values), r
        assert r["max"] == max(r["rounds"])
    results = res["results"]
    shape = (CONFIG.rounds + 1, 1, len(CONFIG.policies), CONFIG.num_seeds)
    for name in ("paper_eval", "lowvar_eval", "explore_success"):
        assert getattr(results, name).shape == shape
    assert np.isnan(results.explore_success[0]).all()  # round 0: no exploration
    action = results.explore_action
    assert action.shape == shape + (CONFIG.explore,)
    assert (action[0] == -1).all() and ((action[1:] >= 0) & (action[1:] < 64)).all()
    # seed diversity: the two seeds explore differently (other poses, other choices)
    assert (action[1:, :, :, 0] != action[1:, :, :, 1]).any()
    assert np.isfinite(results.explore_success[1:]).all()
    assert np.isfinite(results.paper_eval).all() and np.isfinite(results.lowvar_eval).all()
    # evaluate = 2 grasps: fractions in {0, 1/2, 1}; 1 pose x 2 trials likewise
    np.testing.assert_array_equal(results.paper_eval * 2, np.round(results.paper_eval * 2))
    saved = io.load_npz(out / "checkpoint.npz")
    assert int(saved["next_round"]) == CONFIG.rounds + 1
    assert str(saved["fingerprint"]) == res["fingerprint"]
    assert set(res["timings"]) == {"contexts", "choose", "trials", "update", "evaluate"}
    # regret accounting is off by default: NaN, and no regret in the table
    assert np.isnan(results.pseudo_regret).all()
    assert all("pseudo_regret" not in r for r in table)


def test_interrupted_run_resumes_to_same_table(run_a, tiny_theta0, spec, tmp_path):
    res, _, aside = run_a
    shutil.copy(aside, tmp_path / "checkpoint.npz")  # stopped after round 1
    lines = []
    resumed = online.run(CONFIG, [spec], tmp_path, theta0=tiny_theta0, progress=False,
                         log=lines.append)
    assert any("at round 2" in line for line in lines)
    assert resumed["table"] == res["table"]
    for name in res["results"]._fields:
        np.testing.assert_array_equal(getattr(resumed["results"], name),
                                      getattr(res["results"], name), err_msg=name)
    # a finished run reruns to the same table without new work
    again = online.run(CONFIG, [spec], tmp_path, theta0=tiny_theta0, progress=False,
                       log=_quiet)
    assert again["table"] == res["table"]


def test_other_run_in_same_dir_is_refused(run_a, tiny_theta0, spec, tmp_path):
    _, out, _ = run_a
    with pytest.raises(ValueError, match="no objects"):
        online.run(CONFIG, [], tmp_path, theta0=tiny_theta0, progress=False, log=_quiet)
    with pytest.raises(ValueError, match="distinct"):
        online.run(CONFIG, [spec, spec], tmp_path, theta0=tiny_theta0, progress=False,
                   log=_quiet)
    other = online.OnlineConfig(**{**CONFIG.__dict__, "seed": 1})
    with pytest.raises(ValueError, match="different learning run"):
        online.run(other, [spec], out, theta0=tiny_theta0, progress=False, log=_quiet)


def test_common_random_numbers(run_a):
    """Every policy sees the same poses, candidates, uniforms and trial noise: the greedy
    copy (egreedy with ε = 0) reproduces greedy's every figure, and θ0's round-0
    evaluation is the same for all three policies."""
    res, out, _ = run_a
    r = res["results"]
    q = {p: i for i, p in enumerate(CONFIG.policies)}
    for name in r._fields:
        a = getattr(r, name)
        np.testing.assert_array_equal(a[:, :, q["egreedy"]], a[:, :, q["greedy"]],
                                      err_msg=name)
    for name in ("paper_eval", "lowvar_eval"):
        a = getattr(r, name)[0]
        np.testing.assert_array_equal(a[:, q["sern"]], a[:, q["greedy"]])
    # the same grasps (crops) and outcomes went into the two copies' data sets
    saved = io.load_npz(out / "checkpoint.npz")
    for f in ("image", "depth", "label", "weight"):
        b = saved[f"buffer_{f}"]
        np.testing.assert_array_equal(b[:, :, q["egreedy"]], b[:, :, q["greedy"]])


class _HashSimulator:
    """A stand-in simulator whose outcome is a fixed function of (grasp, noise, pose), so
    the test sees any mix-up of rows, noise draws or poses."""

    def __init__(self):
        from sern_jax.grasp import sim as sim_lib

        self.config, self.sim_lib, self.rows = sim_lib.TrialConfig(), sim_lib, 0

    def run_trials(self, grasps, noise, object_pose):
        self.rows += len(grasps)
        h = (grasps @ [3.1, 5.3, 7.7, 0.9] + noise.friction * 11.0 + noise.mass_scale * 2.3
             + noise.grasp_error @ [13.0, 17.0, 19.0, 2.9] + object_pose @ np.arange(1, 8))
        success = np.modf(np.abs(h) * 1e3)[0] > 0.5
        z = np.zeros(len(grasps))
        return self.sim_lib.TrialResult(success, z > 1, z, z, "hash")


def test_shared_trials_equal_simulating_every_copy(spec):
    """_run_trials simulates each distinct (seed, trial, grasp) once: the outcomes equal
    those of simulating every policy's copy with its (shared) noise."""
    from sern_jax.grasp import sim as sim_lib

    rng = np.random.default_rng(0)
    num_s, num_q, num_n = 2, 3, 4
    candidates = rng.normal(size=(num_n, 3, 4))  # 3 candidate grasps per pose
    # q0 and q1 agree everywhere; q2 agrees on poses 0 and 2 only; seed 1 shifts choices.
    choice = np.zeros((num_s, num_q, num_n), int)
    choice[:, 2, 1::2] = 1
    choice[1] = (choice[1] + 1) % 3
    grasps = np.stack([[[candidates[n, choice[s, q, n]] for n in range(num_n)]
                        for q in range(num_q)] for s in range(num_s)])[None]
    poses = rng.normal(size=(1, num_s, num_n, 7))
    keys = [[jax.random.key(100 + s) for s in range(num_s)]]
    simulator, counts = _HashSimulator(), {}
    got = online._run_trials([simulator], grasps, poses, keys, num_n, counts)
    assert counts == {"requested": num_s * num_q * num_n, "simulated": num_s * 6}
    assert simulator.rows == num_s * 6
    want = np.zeros_like(got)
    for s in range(num_s):
        noise = sim_lib.sample_noise(keys[0][s], num_n, simulator.config)
        for q in range(num_q):
            want[0, s, q] = simulator.run_trials(
                grasps[0, s, q], sim_lib.TrialNoise(*(np.asarray(a) for a in noise)),
                poses[0, s]).success
    assert 0 < want.mean() < 1  # the stand-in gives both outcomes: the check has teeth
    np.testing.assert_array_equal(got, want)


def test_native_trial_does_not_depend_on_its_batch(spec):
    """What makes sharing trials exact: a native trial's outcome is the same whatever else
    runs in its batch and in whatever order (MuJoCo is deterministic)."""
    from sern_jax.grasp import sim as sim_lib

    ctx = context.make_contexts(jax.random.key(11), spec, 2)
    simulator = sim_lib.GraspSimulator(ctx.model, chunk=16)
    pi, ki = np.nonzero(np.asarray(ctx.candidates.valid))
    pi, ki = pi[:48], ki[:48]
    grasps = np.asarray(ctx.candidates.grasps, np.float64)[pi, ki]
    poses = np.asarray(ctx.poses)[pi]
    noise = sim_lib.TrialNoise(*(np.asarray(a) for a in sim_lib.sample_noise(
        jax.random.key(4), len(pi), simulator.config)))
    full = simulator.run_trials(grasps, noise, object_pose=poses)
    perm = np.random.default_rng(1).permutation(len(pi))[:20]
    part = simulator.run_trials(grasps[perm], sim_lib.TrialNoise(*(a[perm] for a in noise)),
                                object_pose=poses[perm])
    np.testing.assert_array_equal(part.rise, full.rise[perm])
    np.testing.assert_array_equal(part.success, full.success[perm])


def test_oracle_matches_success_probability(spec):
    """_oracle's first context uses the noise of success_probability(key, ., M): the two
    estimates agree exactly; invalid candidates get 0."""
    from sern_jax.grasp import sim as sim_lib

    ctx = context.make_contexts(jax.random.key(21), spec, 2)
    simulator = sim_lib.GraspSimulator(ctx.model)
    cands = jax.tree.map(lambda x: np.asarray(x)[None, None], ctx.candidates)
    poses = np.asarray(ctx.poses)[None, None]
    key = jax.random.key(5)
    counts = {"requested": 0, "simulated": 0}
    got = online._oracle([simulator], cands, poses, 2, [[key]], counts)
    assert got.shape == (1, 1, 2, 64)
    valid = np.asarray(ctx.candidates.valid)
    want = simulator.success_probability(key, np.asarray(ctx.candidates.grasps)[0], 2,
                                         valid[0], np.asarray(ctx.poses)[0])
    np.testing.assert_array_equal(got[0, 0, 0], want.prob)
    assert (got[0, 0][~valid] == 0).all()
    assert counts["simulated"] == 2 * valid.sum()


def test_regret_accounting(tiny_theta0, spec, tmp_path):
    """With regret_trials, each round's pseudo-regret is finite, in [0, explore], NaN at
    round 0, and reported in the table; greedy's equals best - oracle[chosen]."""
    import dataclasses

    config = dataclasses.replace(CONFIG, policies=("sern", "greedy"), num_seeds=1,
                                 rounds=1, explore=2, regret_trials=2)
    res = online.run(config, [spec], tmp_path, theta0=tiny_theta0, progress=False,
                     log=_quiet)
    pr = res["results"].pseudo_regret
    assert np.isnan(pr[0]).all() and np.isfinite(pr[1:]).all()
    assert (pr[1:] >= -1e-6).all() and (pr[1:] <= config.explore + 1e-6).all()
    assert "oracle" in res["timings"]
    for row in res["table"]:
        assert len(row["pseudo_regret"]) == config.rounds
    from sern_jax.commands import grasp_learn as learn_cli
    assert "Pseudo-regret per round" in learn_cli.format_table(res["table"])
    with pytest.raises(ValueError, match="regret_trials"):
        dataclasses.replace(config, regret_trials=-1)


def test_learner_told_only_failures_lowers_its_scores(tiny_theta0, spec, tmp_path,
                                                      monkeypatch):
    """Every trial fails: after the run, the learner scores the grasps it tried lower than
    θ0 did, in every (seed, policy) copy."""
    monkeypatch.setattr(online, "_run_trials",
                        lambda simulators, grasps, *a: np.zeros(grasps.shape[:4], bool))
    res = online.run(CONFIG, [spec], tmp_path, theta0=tiny_theta0, progress=False,
                     log=_quiet)
    assert (res["results"].paper_eval == 0).all()
    saved = io.load_npz(tmp_path / "checkpoint.npz")
    assert (saved["buffer_label"] == 0).all() and (saved["buffer_weight"] == 1).all()
    template = jax.tree.map(lambda x: x[None, None, None], tiny_theta0.params)
    leaves = [saved[f"p{i}"] for i in range(len(jax.tree.leaves(template)))]
    learned = jax.tree.unflatten(jax.tree.structure(template), leaves)
    net = tiny_theta0.network
    for s in range(CONFIG.num_seeds):
        for q in range(len(CONFIG.policies)):
            image = saved["buffer_image"][0, s, q]
            depth = saved["buffer_depth"][0, s, q]
            before = np.asarray(net.apply(tiny_theta0.params, image, depth))
            after = np.asarray(net.apply(jax.tree.map(lambda x: x[0, s, q], learned),
                                         image, depth))
            assert (after < before).all(), (s, q, before, after)
            assert after.mean() < before.mean() - 0.05


def test_sern_choices_follow_softmax_over_valid(tiny_theta0, spec):
    """make_choose's SERN draws, over many uniforms on one context, match softmax(r̂/α)
    restricted to the valid slots; invalid slots are never chosen."""
    ctx = context.make_contexts(jax.random.key(5), spec, 1)
    valid = np.asarray(ctx.candidates.valid).copy()
    valid[0, ::4] = False  # some invalid slots, among them possibly the best
    cands = ctx.candidates._replace(valid=jnp.asarray(valid))
    choose = online.make_choose(tiny_theta0.network, ("sern",))
    params = jax.tree.map(lambda x: x[None], tiny_theta0.params)
    num = 40_000
    u = jax.random.uniform(jax.random.key(6), (num, 1))
    one = jax.jit(choose)
    _, r_hat, _, _ = one(params, ctx.depth, cands, u[0], jnp.ones(1), 0.0)
    r = np.asarray(r_hat, np.float64)[0, 0]
    v = valid[0]
    alpha = jnp.asarray([(r[v].max() - r[v].min()) / 3])  # a law that is not flat
    _, _, probs, _ = one(params, ctx.depth, cands, u[0], alpha, 0.0)
    # many uniforms, one context: only the action is batched (crops and r̂ are computed once)
    many = jax.jit(jax.vmap(lambda uu: choose(params, ctx.depth, cands, uu, alpha, 0.0)[0]))
    action = np.asarray(many(u)).reshape(-1)
    alpha = float(alpha[0])
    z = np.where(v, r / alpha, -np.inf)
    exact = np.exp(z - z.max())
    exact /= exact.sum()
    np.testing.assert_allclose(np.asarray(probs)[0, 0], exact, atol=1e-5)
    assert v[action].all() and (action >= 0).all()  # never an invalid slot
    counts = np.bincount(action, minlength=v.size)[v]
    assert 0.5 * np.abs(counts / num - exact[v]).sum() < 0.02  # total variation
    # chi-square goodness of fit; fixed keys make the test deterministic, its false-alarm
    # rate on fresh keys would be 1e-4. The same counts reject a wrong temperature (2α).
    assert _chisquare_p(counts, exact[v]) > 1e-4
    wrong = np.exp(z / 2 - z.max() / 2)
    assert _chisquare_p(counts, wrong[v] / wrong[v].sum()) < 1e-4


def _chisquare_p(counts, probs):
    """Pearson's chi-square p-value, cells pooled (smallest first) to expected counts >= 5."""
    expected = probs * counts.sum()
    obs, exp, acc_o, acc_e = [], [], 0.0, 0.0
    for i in np.argsort(expected):
        acc_o, acc_e = acc_o + counts[i], acc_e + expected[i]
        if acc_e >= 5:
            obs.append(acc_o)
            exp.append(acc_e)
            acc_o = acc_e = 0.0
    obs[-1] += acc_o
    exp[-1] += acc_e
    assert len(obs) >= 5
    return scipy.stats.chisquare(obs, exp).pvalue


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("field, value, match", [
    ("policies", ("sern", "foo"), "unknown policy"), ("policies", (), "policies"),
    ("policies", ("sern", "sern"), "repeat"), ("alpha", 0.0, "alpha"),
    ("alpha", -1.0, "alpha"), ("rounds", 0, "rounds"), ("num_seeds", 0, "num_seeds"),
    ("epsilon", 1.5, "epsilon"), ("eval_poses", -1, "eval_poses"), ("p", 1.0, "p must"),
    ("core_set", "dpp2", "core_set"), ("loss", "mse", "loss"), ("backend", "gpu", "backend"),
])
def test_bad_config_is_a_clear_error(field, value, match):
    with pytest.raises(ValueError, match=match):
        online.OnlineConfig(**{field: value})


@pytest.mark.parametrize("argv, match", [
    (["--policies", "sern,foo"], "unknown policy 'foo'"),
    (["--alpha", "0"], "alpha must be > 0"),
    (["--alpha", "-0.5"], "alpha must be > 0"),
    (["--eval-poses", "-1"], "--eval-poses must be an integer >= 0"),
    (["--regret-trials", "-2"], "--regret-trials must be an integer >= 0"),
    (["--eval-trials", "0"], "--eval-trials must be >= 1 when --eval-poses > 0"),
    (["--p", "1.5"], "--p must be in (0, 1)"),
    (["--mesh", "/nonexistent/part.obj"], "mesh file not found"),
    (["small_box", "small_box"], "given twice"),
])
def test_learn_cli_bad_input_fails_fast(argv, match, capsys, monkeypatch, tmp_path):
    def unreachable(*a, **k):
        raise AssertionError("bad input reached online.run")

    monkeypatch.setattr(online, "run", unreachable)
    monkeypatch.setattr(artifacts, "DATA_DIR", tmp_path / "no_theta0")  # no shipped θ0
    artifacts._load.cache_clear()
    t = time.perf_counter()
    status = cli.main(["grasp", "learn", "--out", str(tmp_path / "run"), *argv])
    assert time.perf_counter() - t < 5.0
    err = capsys.readouterr().err
    assert status == 2
    assert match in err and err.count("\n") == 1, err


def test_run_fingerprint_sees_geometry(tiny_theta0, spec):
    """The same name with other geometry (a mesh at another --mesh-units) is another run."""
    import dataclasses

    scaled = dataclasses.replace(spec, geoms=tuple(
        dataclasses.replace(g, size=tuple(2 * x for x in g.size),
                            vertices=tuple(tuple(2 * x for x in v) for v in g.vertices))
        for g in spec.geoms))
    assert scaled.name == spec.name
    assert (online.run_fingerprint(CONFIG, [spec], tiny_theta0)
            != online.run_fingerprint(CONFIG, [scaled], tiny_theta0))
    assert (online.run_fingerprint(CONFIG, [spec], tiny_theta0)
            == online.run_fingerprint(CONFIG, [objects.make_object(OBJECT)], tiny_theta0))


def test_learn_cli_zero_rounds_is_an_argument_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["grasp", "learn", "--rounds", "0"])
    assert exc.value.code == 2
    assert "must be >= 1" in capsys.readouterr().err


@pytest.mark.parametrize("argv, match", [
    (["--policies", "foo"], "unknown policy"),
    (["--mesh", "BROKEN"], "not a readable mesh"),
])
def test_learn_cli_subprocess_one_line_no_traceback(argv, match, tmp_path):
    broken = tmp_path / "broken.obj"
    broken.write_text("v 0 0 0\nf 1 2 3\n")
    argv = [str(broken) if a == "BROKEN" else a for a in argv]
    t = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "sern_jax.commands.main", "grasp", "learn", "--out",
         str(tmp_path / "run"), *argv], capture_output=True, text=True, timeout=120)
    seconds = time.perf_counter() - t
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("Failed to import")]
    assert len(lines) == 1 and match in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
    assert seconds < 30  # interpreter and imports only: nothing compiles
