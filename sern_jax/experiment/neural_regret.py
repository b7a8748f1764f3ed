"""Regret curves of neural learners on exact-reward problems (``sern regret --estimator neural``).

Thin main over the library: builds the problem (:mod:`sern_jax.core.contextual_problems`), the
network (:mod:`sern_jax.engine.networks`) and each learner from the registry
(:mod:`sern_jax.learners.registry`, the same modules ``sern grasp learn`` runs), runs seeds
with :func:`sern_jax.engine.neural.run_seeds` in chunks saved as they finish (so a rerun of
the same command resumes), and writes the run directory in the layout of the tabular
experiment (``sern_jax/experiment/regret.py``, whose chunk bookkeeping and summary it reuses):
``config.json``, ``metadata.json``, ``results.npz`` (``<policy>__<field>`` [S, G, ...], ``t``,
``means``), ``summary.json`` keyed by policy with ``regret_T_mean``, ``report.md``.

Regret is in the problem's units (the wheel's 50); the learners fit rewards scaled to [0, 1].
With ``uniform`` among the policies, ``summary.json`` also holds each policy's cumulative
regret divided by Uniform's (``normalised_by_uniform``), Riquelme et al.'s measure.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from sern_jax.infra import io

from . import regret as _tab

__all__ = ["ALIASES", "NeuralRegretExperiment", "run_experiment", "run_delta_sweep",
           "summarise", "build_runs"]

# Tabular policy names that mean the same learner here (one name, one thing).
ALIASES = {"softmax": "sern", "epsilon_greedy": "egreedy"}
FIELDS = _tab.FIELDS


@dataclasses.dataclass(frozen=True)
class NeuralRegretExperiment:
    """Everything that defines a neural regret run (saved as ``config.json``)."""

    policies: tuple[str, ...] = ("sern", "egreedy", "greedy", "uniform")
    estimator: str = "neural"
    problem: str = "wheel"  # wheel | finite | linear
    delta: float = 0.95  # the wheel's δ
    num_arms: int = 5
    num_contexts: int = 10  # finite problem: M
    gap: float = 0.1  # finite problem: Δ2
    context_dim: int = 4  # finite / linear: d
    horizon: int = 2000
    num_seeds: int = 100
    update_every: int = 50
    hidden: tuple[int, ...] = (50, 50)
    fit_steps: int = 20
    batch_size: int = 64
    learning_rate: float = 1e-2
    alpha0: float = 0.1  # sern's α (sern_log's α0)
    p: float = 0.3
    epsilon: float = 0.1
    schedule: str = "constant"  # sern's α is fixed (sern_log: α0/ln(T^p)); for the figures
    seed: int = 0
    num_checkpoints: int = 16
    chunk_size: int = 100
    nl_prior_mean: str = "network"  # neural_lints/neural_linucb: --nl-prior-mean
    nl_sigma2: str = "pooled"  # neural_lints/neural_linucb: --nl-sigma2 (pooled | arm)

    def fingerprint(self) -> str:
        """Hash of the fields that change results (not the chunk size). The Neural-Linear
        options enter only when neural_lints or neural_linucb is among the policies (they
        change nothing else) and differ from what every run made before they existed used
        (network, arm), so those runs keep their fingerprint and resume: a Neural-Linear run
        made before the pooled default resumes with ``--nl-sigma2 arm``."""
        d = dataclasses.asdict(self)
        d.pop("chunk_size")
        uses_nl = any(_learner_name(p) in NL_LEARNERS for p in self.policies)
        for name, before in _LEGACY.items():
            if not uses_nl or d[name] == before:  # they change nothing without those learners
                d.pop(name)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


# Neural-Linear options and the value runs made before the option existed used.
_LEGACY = {"nl_prior_mean": "network", "nl_sigma2": "arm"}
NL_LEARNERS = ("neural_lints", "neural_linucb")  # the learners the nl_* options act on


def _learner_name(policy: str) -> str:
    return ALIASES.get(policy, policy)


def _check(exp: NeuralRegretExperiment) -> None:
    """Option values, naming the flag (before any trace or compile)."""
    from sern_jax.learners import registry

    if not exp.policies:
        raise ValueError("--policies is empty; give a comma list such as 'sern,greedy,uniform'")
    names = [_learner_name(p) for p in exp.policies]
    if len(set(names)) != len(names):
        raise ValueError(f"--policies names one learner twice (aliases: {ALIASES}): "
                         f"{','.join(exp.policies)}")
    known = tuple(registry.names()) + ("uniform",)
    for policy, name in zip(exp.policies, names):
        if name not in known:
            raise ValueError(f"--policies: unknown policy {policy!r} with --estimator neural; "
                             f"choose from {', '.join(known)} (aliases: softmax, "
                             f"epsilon_greedy)")
    _tab.check_integer("--seeds", exp.num_seeds, 1, 2**32)
    _tab.check_integer("--horizon", exp.horizon, 1, 2**24)
    _tab.check_integer("--update-every", exp.update_every, 1)
    _tab.check_integer("--checkpoints", exp.num_checkpoints, 1, 100_000)
    _tab.check_integer("--chunk-size", exp.chunk_size, 1)
    _tab.check_integer("--seed", exp.seed, 0, 2**32 - 1)
    _tab.check_integer("--fit-steps", exp.fit_steps, 1, 100_000)
    _tab.check_integer("--batch-size", exp.batch_size, 1, 1_000_000)
    if exp.horizon % exp.update_every:
        raise ValueError(f"--horizon {exp.horizon} must be a multiple of --update-every "
                         f"{exp.update_every} (rounds come in whole phases)")
    if not exp.hidden or any(isinstance(w, bool) or not isinstance(w, (int, np.integer))
                             or not 1 <= w <= 4096 for w in exp.hidden):
        raise ValueError(f"--hidden must be a comma list of widths in [1, 4096], got "
                         f"{','.join(map(str, exp.hidden)) or 'nothing'}")
    for flag, value in (("--alpha", exp.alpha0), ("--p", exp.p), ("--epsilon", exp.epsilon),
                        ("--learning-rate", exp.learning_rate), ("--delta", exp.delta),
                        ("--gap", exp.gap)):
        if not math.isfinite(value):
            raise ValueError(f"{flag} must be a finite number, got {value!r}")
    if not exp.learning_rate >= float(np.finfo(np.float32).tiny) or exp.learning_rate > 1e30:
        raise ValueError(f"--learning-rate must be a positive normal float32 number, got "
                         f"{exp.learning_rate!r}")
    from sern_jax.learners import neural_linear

    if exp.nl_prior_mean not in neural_linear.PRIOR_MEANS:
        raise ValueError(f"--nl-prior-mean must be one of "
                         f"{', '.join(neural_linear.PRIOR_MEANS)}, got {exp.nl_prior_mean!r}")
    if exp.nl_sigma2 not in neural_linear.SIGMA2_MODES:
        raise ValueError(f"--nl-sigma2 must be one of {', '.join(neural_linear.SIGMA2_MODES)}, "
                         f"got {exp.nl_sigma2!r}")
    if not 0.0 <= exp.epsilon <= 1.0:
        raise ValueError(f"--epsilon must lie in [0, 1], got {exp.epsilon!r}")
    if exp.problem == "wheel" and not 0.0 < exp.delta < 1.0:
        raise ValueError(f"--delta must lie in (0, 1), got {exp.delta!r}")
    if exp.problem == "finite" and not 0.0 < exp.gap < 1.0:
        raise ValueError(f"--gap must lie in (0, 1), got {exp.gap!r}")
    from sern_jax.infra import validate

    for flag, value in (("--alpha", exp.alpha0), ("--p", exp.p)):
        validate.finite_float(value, flag, float32_normal=True)  # the learners' float32
    _tab.check_integer("--arms", exp.num_arms, 2, MAX_ARMS)
    _tab.check_integer("--contexts", exp.num_contexts, 1, MAX_CONTEXTS)
    _tab.check_integer("--context-dim", exp.context_dim, 1, MAX_CONTEXT_DIM)
    if exp.schedule != "constant":
        raise ValueError(f"--schedule applies to the tabular estimators; with --estimator "
                         f"neural use --policies sern (fixed --alpha) or sern_log "
                         f"(α = --alpha/ln(T^--p)), got --schedule {exp.schedule!r}")


# Sizes beyond any useful neural run (the network scores every arm each round): refused up
# front with the flag named, before the budget below is even estimated.
MAX_ARMS = 4096
MAX_CONTEXTS = 2**24
MAX_CONTEXT_DIM = 65_536
_MAX_DAYS = 7.0  # refuse runs estimated to take longer than this
_FLOPS = 2.0e9  # a conservative single-core float32 rate, for the up-front time estimate


def estimate(exp: NeuralRegretExperiment) -> dict:
    """Up-front memory, disk and time of the run from the flags alone (no trace, no
    compile): the problem's tables, each seed's network, optimiser state and replay buffer
    (inputs are a context and a one-hot arm), the saved curves, and the network's forward
    passes (every arm, every round) and fitting steps."""
    d, k, m = exp.context_dim, exp.num_arms, exp.num_contexts
    if exp.problem == "wheel":
        d, k, m = 2, 5, 1
    width = d + k  # the network's input: context ⊕ one-hot arm
    layers = [width, *exp.hidden, 1]
    params = sum(a * b + b for a, b in zip(layers[:-1], layers[1:]))
    last = exp.hidden[-1] if exp.hidden else 1
    problem_floats = m * (k + d) if exp.problem == "finite" else k * d
    per_seed = (4 * params  # parameters, two Adam moments, a gradient
                + exp.horizon * (width + 2)  # replay buffer
                + k * (last + 1) ** 2 * 2  # Neural-Linear posteriors (precision, covariance)
                + exp.batch_size * sum(layers)  # activations of a fitting step
                + k * sum(layers))  # activations of scoring every arm
    chunk = min(exp.chunk_size, exp.num_seeds)
    memory = 4 * (problem_floats + 2 * chunk * per_seed)
    saved = exp.num_seeds * len(exp.policies) * exp.num_checkpoints * (len(FIELDS) + k) * 4
    flops = exp.num_seeds * len(exp.policies) * (
        exp.horizon * k * 2 * params
        + (exp.horizon // max(exp.update_every, 1)) * exp.fit_steps * exp.batch_size * 6
        * params)
    return {"memory_bytes": memory + 2 * saved, "disk_bytes": 2 * saved,
            "seconds": flops / _FLOPS}


def check_fits(exp: NeuralRegretExperiment, out_dir: Path | None = None) -> dict:
    """Refuses (``ValueError`` naming the flags) a run whose :func:`estimate` exceeds this
    machine's available memory, the free disk under ``out_dir`` or a week: before any
    array is made or anything compiles."""
    import shutil

    from sern_jax.engine import drive

    est = estimate(exp)
    avail = drive.available_memory_bytes()
    sizes = (f"--arms {exp.num_arms}, --contexts {exp.num_contexts}, --context-dim "
             f"{exp.context_dim}, --hidden {','.join(map(str, exp.hidden))}, --horizon "
             f"{exp.horizon}, --chunk-size {min(exp.chunk_size, exp.num_seeds)}")
    if est["memory_bytes"] > avail:
        raise ValueError(f"{sizes} needs about {io.fmt_bytes(est['memory_bytes'])} of memory, "
                         f"more than the {io.fmt_bytes(avail)} available; use smaller sizes")
    if out_dir is not None:
        probe = Path(out_dir)
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        free = shutil.disk_usage(probe).free
        if est["disk_bytes"] > free:
            raise ValueError(f"the run needs up to {io.fmt_bytes(est['disk_bytes'])} of disk "
                             f"under --out {out_dir}, more than the {io.fmt_bytes(free)} free; "
                             "use fewer --seeds, --checkpoints or --arms")
    if est["seconds"] > _MAX_DAYS * 86400:
        raise ValueError(f"--seeds {exp.num_seeds} x --horizon {exp.horizon} x "
                         f"{len(exp.policies)} policies with {sizes} is estimated at "
                         f"{io.fmt_time(est['seconds'])}, over the {_MAX_DAYS:g}-day limit; use "
                         "smaller sizes")
    return est


def _hyper(exp: NeuralRegretExperiment) -> dict:
    """Command-line values by the registry's hyperparameter names (--alpha is sern's α and
    sern_log's α0)."""
    return {"alpha": exp.alpha0, "alpha0": exp.alpha0, "p": exp.p, "epsilon": exp.epsilon,
            "nl_prior_mean": exp.nl_prior_mean, "nl_sigma2": exp.nl_sigma2}


def build_runs(exp: NeuralRegretExperiment):
    """Validated ``[(policy, run)]`` and the problem: every check (flags, problem, learner
    hyperparameters, shapes) happens here, before anything compiles."""
    from sern_jax.core import contextual_problems as cp
    from sern_jax.engine import networks
    from sern_jax.engine import neural as nr
    from sern_jax.learners import base, registry

    _check(exp)
    check_fits(exp)
    problem = cp.make_problem(exp.problem, delta=exp.delta, num_arms=exp.num_arms,
                              num_contexts=exp.num_contexts, gap=exp.gap,
                              context_dim=exp.context_dim, seed=exp.seed)
    cfg = nr.NeuralRunConfig(horizon=exp.horizon, update_every=exp.update_every,
                             num_checkpoints=exp.num_checkpoints)
    nr.validate(cfg, exp.num_seeds)
    train = base.TrainConfig(horizon=exp.horizon, fit_steps=exp.fit_steps,
                             batch_size=exp.batch_size, learning_rate=exp.learning_rate)
    model = networks.mlp_model(problem.num_arms, problem.context_dim, exp.hidden)
    hyper = _hyper(exp)
    learners = []
    for policy in exp.policies:
        name = _learner_name(policy)
        if name == "uniform":
            learners.append((policy, nr.uniform_learner(problem.num_arms)))
        else:
            learners.append((policy, registry.make(name, model, train,
                                                   registry.make_config(name, hyper))))
    runs = [(policy, nr.make_run(cfg, problem, learner, model)) for policy, learner in learners]
    return runs, problem, cfg


def run_experiment(exp: NeuralRegretExperiment, out_dir: str | Path, *, progress: bool = True,
                   log=print, sweep_cache: dict | None = None) -> Path:
    """Runs (or resumes) the experiment into ``out_dir``; returns the run directory.

    Everything is validated before anything is written or compiled; a run that fails before
    saving any seeds leaves no directory behind.

    ``sweep_cache`` (a dict kept across calls): on the wheel, the runs are built once per
    experiment-but-δ and δ is passed as a traced argument (``WheelParams``), so the calls of
    a δ sweep share one compilation per policy (:func:`run_delta_sweep`).
    """
    run_dir = Path(out_dir)
    from sern_jax.infra import validate

    validate.out_dir(run_dir, "--out")  # tried for real, nothing left behind; before any jax
    _check(exp)  # the flags, the size budget and the run directory before anything is traced
    est = check_fits(exp, run_dir)
    _check_run_dir(exp, run_dir)
    params = None
    if sweep_cache is not None and exp.problem == "wheel":
        from sern_jax.core import contextual_problems as cp

        key = dataclasses.replace(exp, delta=0.5, chunk_size=1).fingerprint()
        if key not in sweep_cache:
            sweep_cache[key] = build_runs(exp)
        runs, _, cfg = sweep_cache[key]
        problem = cp.make_problem("wheel", delta=exp.delta, num_arms=exp.num_arms)
        params = problem.params
    else:
        runs, problem, cfg = build_runs(exp)
    if est["seconds"] > 60 and progress:
        log(f"estimated run time ~{io.fmt_time(est['seconds'])} at most "
            f"({io.fmt_bytes(est['memory_bytes'])} of memory)")
    # created and locked in one step; a directory this run created is removed again, under
    # the lock, when it fails before saving any seeds
    with io.run_lock(run_dir, remove_unused=_tab.no_chunks_saved):
        return _run(exp, runs, problem, cfg, run_dir, progress, log, params)


def _run(exp, runs, problem, cfg, run_dir: Path, progress: bool, log=print,
         params=None) -> Path:
    from sern_jax.engine import neural as nr

    (run_dir / "figures").mkdir(exist_ok=True)
    chunk_dir = run_dir / "chunks"
    chunk_dir.mkdir(exist_ok=True)
    for path in sorted(chunk_dir.glob("*.npz")):  # damaged chunks are set aside, recomputed
        io.npz_unit_done(path, log)
    t = nr.checkpoint_times(cfg)
    io.save_json(run_dir / "config.json",
                 {"experiment": exp, "fingerprint": exp.fingerprint(), "checkpoints": t})
    chunk = min(exp.chunk_size, exp.num_seeds)
    ranges = [(a, min(a + chunk, exp.num_seeds)) for a in range(0, exp.num_seeds, chunk)]
    per_call = chunk  # one call at a time (neural_runner.run_seeds: workers=1)
    bar = _tab._progress_bar(len(runs) * exp.num_seeds, progress)
    for policy, run in runs:
        for a, b in ranges:
            if _tab._cover(_tab._saved_ranges(chunk_dir, policy), a, b) is not None:
                bar.update(b - a)
                continue
            start_time = time.perf_counter()
            out = nr.run_seeds(run, exp.seed, b - a, first_seed=a, chunk_size=per_call,
                               params=params)
            io.save_npz(chunk_dir / _tab._chunk_name(policy, a, b),
                        wall_s=np.float64(time.perf_counter() - start_time),
                        **{f: getattr(out, f) for f in FIELDS})
            bar.update(b - a)
    bar.close()
    merged, timings = {}, {}
    for policy, _ in runs:
        saved = _tab._saved_ranges(chunk_dir, policy)
        parts = [_tab._load_range(saved, a, b) for a, b in ranges]
        timings[policy] = sum(p["wall_s"] for p in parts)
        for f in FIELDS:
            merged[f"{policy}__{f}"] = np.concatenate([p[f] for p in parts], axis=0)
    merged["t"] = t
    merged["means"] = np.asarray(problem.arm_means)[None, :]
    io.save_npz(run_dir / "results.npz", **merged)
    meta = io.run_metadata(wall_seconds_per_policy=timings)
    io.save_json(run_dir / "metadata.json", meta)
    summary = summarise(exp, merged)
    io.save_json(run_dir / "summary.json", summary)
    _write_report(run_dir, exp, problem, summary, meta)
    return run_dir


def _check_run_dir(exp: NeuralRegretExperiment, run_dir: Path) -> None:
    """``run_dir`` is absent, or a directory holding this experiment (its fingerprint):
    ``io.check_run_dir``."""
    io.check_run_dir(run_dir, exp.fingerprint())


def run_delta_sweep(exp: NeuralRegretExperiment, deltas, out_root: str | Path, *,
                    progress: bool = True, log=print) -> list[Path]:
    """The wheel experiment at every δ of ``deltas``, one run directory each
    (``out_root/d<δ>``), sharing one compilation per policy (δ is a traced argument). Every
    δ is validated before anything runs; each directory resumes on its own."""
    from sern_jax.core import contextual_problems as cp

    if exp.problem != "wheel":
        raise ValueError("--deltas applies to --problem wheel")
    deltas = [float(d) for d in deltas]
    if not deltas or len(set(deltas)) != len(deltas):
        raise ValueError(f"--deltas must list distinct values, got {deltas}")
    for d in deltas:
        if not (math.isfinite(d) and 0.0 < d < 1.0):
            raise ValueError(f"--deltas: every δ must lie in (0, 1), got {d!r}")
    names = [f"d{d:g}" for d in deltas]
    if len(set(names)) != len(names):
        raise ValueError(f"--deltas: values that share a run directory name "
                         f"({', '.join(names)}); give δ that differ in 6 significant digits")
    for d, name in zip(deltas, names):  # everything refused before the first δ runs
        cp.make_problem("wheel", delta=d, num_arms=exp.num_arms)
        _check(dataclasses.replace(exp, delta=d))
        _check_run_dir(dataclasses.replace(exp, delta=d), Path(out_root) / name)
    cache: dict = {}
    return [run_experiment(dataclasses.replace(exp, delta=d), Path(out_root) / name,
                           progress=progress, log=log, sweep_cache=cache)
            for d, name in zip(deltas, names)]


def _ratio_interval(num: np.ndarray, den: np.ndarray, num_boot: int = 2000,
                    seed: int = 0) -> tuple[float, float, float]:
    """mean(num)/mean(den) over paired seeds (common random numbers) with a 95% percentile
    bootstrap interval that resamples seeds (pairs kept)."""
    ratio = float(num.mean() / den.mean())
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, num.size, (num_boot, num.size))
    boots = num[idx].mean(1) / den[idx].mean(1)
    return ratio, float(np.percentile(boots, 2.5)), float(np.percentile(boots, 97.5))


def summarise(exp: NeuralRegretExperiment, merged: dict) -> dict:
    """The tabular experiment's summary (per policy: ``regret_T_mean``, its Student-t 95%
    interval, both definitions, the log–log slope, min π), plus ``normalised_by_uniform``
    when Uniform ran: R_T(policy)/R_T(uniform), Riquelme et al.'s measure, with a paired
    seed-bootstrap 95% interval."""
    out = _tab.summarise(exp, merged)
    out["problem"] = exp.problem
    out["regret_units"] = "the problem's reward units (the wheel's 50 is 50)"
    if "uniform" in exp.policies:
        den = merged["uniform__regret_rb"][:, -1].astype(np.float64)
        norm = {}
        for policy in exp.policies:
            num = merged[f"{policy}__regret_rb"][:, -1].astype(np.float64)
            r, lo, hi = _ratio_interval(num, den)
            norm[policy] = {"ratio": r, "ci95_bootstrap": [lo, hi]}
        out["normalised_by_uniform"] = norm
    return out


def _write_report(run_dir: Path, exp, problem, summary: dict, meta: dict) -> None:
    lines = [
        "# Neural regret-curve run", "",
        f"Problem {problem.name} ({exp.problem}), K={problem.num_arms}, d={problem.context_dim};"
        f" T={exp.horizon}, seeds={exp.num_seeds}, root seed {exp.seed}. Network: MLP "
        f"{list(exp.hidden)}, {exp.fit_steps} Adam steps (batch {exp.batch_size}, lr "
        f"{exp.learning_rate}) every {exp.update_every} rounds; α={exp.alpha0} (sern; "
        f"sern_log's α0, p={exp.p}), ε={exp.epsilon}.", "",
        "Regret is Rao–Blackwellised pseudo-regret in the problem's units, Σ_t (max_a r_a(x_t)"
        " − Σ_a π_t(a) r_a(x_t)), mean over seeds with a 95% Student-t interval (n − 1 dof); "
        "the paper's R_T uses max_a E_x r_a(x).", "",
        "| policy | R_T (mean) | 95% CI | R_T/T | paper's R_T | slope (last decade) |"
        + (" R_T / Uniform's [95% bootstrap] |" if "normalised_by_uniform" in summary else ""),
        "|---|---|---|---|---|---|" + ("---|" if "normalised_by_uniform" in summary else ""),
    ]
    for policy, s in summary["policies"].items():
        sl = s["slope_last_decade"]
        row = (f"| {policy} | {s['regret_T_mean']:.2f} | [{s['regret_T_ci95'][0]:.2f}, "
               f"{s['regret_T_ci95'][1]:.2f}] | {s['regret_over_T']:.4f} | "
               f"{s['regret_paper_T_mean']:.2f} | {sl['slope']:.3f} [{sl['lo']:.3f}, "
               f"{sl['hi']:.3f}] |")
        if "normalised_by_uniform" in summary:
            n = summary["normalised_by_uniform"][policy]
            row += f" {n['ratio']:.3f} [{n['ci95_bootstrap'][0]:.3f}, " \
                   f"{n['ci95_bootstrap'][1]:.3f}] |"
        lines.append(row)
    lines += ["", f"Made with sern_jax {meta['versions'].get('sern_jax')}, jax "
              f"{meta['versions'].get('jax')}, commit {meta.get('git_commit')}."]
    (run_dir / "report.md").write_text("\n".join(lines) + "\n")
