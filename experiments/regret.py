"""Regret-curve experiment: several policies, one problem, many seeds, saved run directory.

Thin main over the library (STYLE.md §4): builds configs, runs ``executor.run_seeds`` per policy
in seed chunks, saves each finished chunk atomically (so an interrupted run resumes where it
stopped), merges them into ``results.npz`` and writes ``report.md``. Plotting lives in
``figures/make_regret_figs.py`` and reads the saved results only.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np

from sern_jax import io

__all__ = ["RegretExperiment", "run_experiment", "summarise", "FIELDS"]

FIELDS = ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "counts", "compensator",
          "min_prob")


@dataclasses.dataclass(frozen=True)
class RegretExperiment:
    """Everything that defines a regret-curve run (saved as ``config.json``)."""

    policies: tuple[str, ...] = ("softmax", "epsilon_greedy", "greedy", "ucb1",
                                 "boltzmann_gumbel")
    estimator: str = "addhalf"
    num_arms: int = 10
    means: str = "linspace"  # "linspace" (0.9 → 0.1), "random" (per seed), or "m1,m2,..."
    num_contexts: int = 1
    gap: float = 0.1  # Δ2 of the random contextual problem (num_contexts > 1)
    horizon: int = 10_000
    num_seeds: int = 2000
    schedule: str = "constant"
    alpha0: float = 0.1
    p: float = 0.3
    epsilon: float = 0.1
    seed: int = 0
    num_checkpoints: int = 32
    chunk_size: int = 1000
    float64: bool = False
    devices: int = 1

    def fingerprint(self) -> str:
        """Hash of the fields that change results (not chunk size or devices)."""
        d = dataclasses.asdict(self)
        d.pop("chunk_size")
        d.pop("devices")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _problem(exp: RegretExperiment, dtype):
    import jax

    from sern_jax import problems

    if exp.num_contexts > 1:
        return problems.contextual_with_gap(jax.random.key(exp.seed + 10_007), exp.num_contexts,
                                            exp.num_arms, exp.gap, dtype=dtype), False
    if exp.means == "linspace":
        return problems.bernoulli(np.linspace(0.9, 0.1, exp.num_arms), dtype=dtype), False
    if exp.means == "random":
        return problems.bernoulli(np.full(exp.num_arms, 0.5), dtype=dtype), True
    try:
        values = [float(v) for v in exp.means.split(",")]
    except ValueError:
        raise ValueError(f"--means must be 'linspace', 'random' or a comma list of numbers, "
                         f"got {exp.means!r}") from None
    if len(values) != exp.num_arms:
        raise ValueError(f"--means has {len(values)} values but --arms is {exp.num_arms}")
    return problems.bernoulli(values, dtype=dtype), False


def _configs(exp: RegretExperiment):
    """Validated (policy, RunConfig, RunParams) triples; raises before any compile."""
    import jax.numpy as jnp

    from sern_jax import simulate as sim

    dtype = jnp.float64 if exp.float64 else jnp.float32
    for policy in exp.policies:  # names, sizes and dtype first: clearer errors
        sim.validate(sim.RunConfig(policy=policy, estimator=exp.estimator,
                                   schedule=exp.schedule, num_arms=exp.num_arms,
                                   horizon=exp.horizon, num_contexts=exp.num_contexts,
                                   num_checkpoints=exp.num_checkpoints,
                                   dtype="float64" if exp.float64 else "float32"))
    problem, random_means = _problem(exp, dtype)
    if exp.num_seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {exp.num_seeds}")
    if exp.chunk_size < 1:
        raise ValueError(f"--chunk-size must be >= 1, got {exp.chunk_size}")
    out = []
    for policy in exp.policies:
        cfg = sim.RunConfig(policy=policy, estimator=exp.estimator, schedule=exp.schedule,
                            num_arms=exp.num_arms, horizon=exp.horizon,
                            num_contexts=exp.num_contexts, num_checkpoints=exp.num_checkpoints,
                            dtype="float64" if exp.float64 else "float32",
                            random_means=random_means)
        params = sim.default_params(cfg, problem, alpha0=exp.alpha0, p=exp.p,
                                    epsilon=exp.epsilon)
        sim.validate(cfg, params, exp.num_seeds)
        out.append((policy, cfg, params))
    return out


def run_experiment(exp: RegretExperiment, out_dir: str | Path, *, progress: bool = True,
                   log=print) -> Path:
    """Runs (or resumes) the experiment into ``out_dir``; returns the run directory."""
    import jax

    from sern_jax import executor
    from sern_jax import simulate as sim

    ctx = jax.enable_x64() if exp.float64 else _nullcontext()
    with ctx:
        triples = _configs(exp)  # validation before any compile
        run_dir = Path(out_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "figures").mkdir(exist_ok=True)
        chunk_dir = run_dir / "chunks"
        chunk_dir.mkdir(exist_ok=True)
        cfg_path = run_dir / "config.json"
        if cfg_path.exists():
            old = io.load_json(cfg_path)
            if old.get("fingerprint") != exp.fingerprint():
                raise ValueError(f"{run_dir} holds a different experiment (fingerprint "
                                 f"{old.get('fingerprint')} != {exp.fingerprint()}); "
                                 f"choose another --out or delete it")
        io.save_json(cfg_path, {"experiment": exp, "fingerprint": exp.fingerprint(),
                                "checkpoints": sim.checkpoint_times(triples[0][1])})
        mesh = None
        if exp.devices > 1:
            from sern_jax.sharding import seed_mesh

            mesh = seed_mesh(exp.devices)
        chunk = min(exp.chunk_size, exp.num_seeds)
        num_chunks = math.ceil(exp.num_seeds / chunk)
        # one fixed call shape for every saved chunk (the last, smaller one too), split so that
        # each core runs its own calls
        per_call = math.ceil(chunk / executor.concurrent_calls(mesh))
        bar = _progress_bar(len(triples) * exp.num_seeds, progress)
        timings = {}
        for policy, cfg, params in triples:
            start_time = time.perf_counter()
            ran = False
            for c in range(num_chunks):
                path = chunk_dir / f"{policy}_{c:05d}.npz"
                size = min(chunk, exp.num_seeds - c * chunk)
                if path.exists():
                    bar.update(size)
                    continue
                out = executor.run_seeds(cfg, params, exp.seed, size, first_seed=c * chunk,
                                         chunk_size=per_call, mesh=mesh)
                io.save_npz(path, **{f: getattr(out, f) for f in FIELDS})
                ran = True
                bar.update(size)
            if ran:
                timings[policy] = time.perf_counter() - start_time
        bar.close()
        merged = {}
        for policy, _, _ in triples:
            parts = [io.load_npz(chunk_dir / f"{policy}_{c:05d}.npz") for c in range(num_chunks)]
            for f in FIELDS:
                merged[f"{policy}__{f}"] = np.concatenate([p[f] for p in parts], axis=0)
        merged["t"] = sim.checkpoint_times(triples[0][1])
        merged["means"] = np.asarray(triples[0][2].problem.means)
        io.save_npz(run_dir / "results.npz", **merged)
        meta = io.run_metadata(wall_seconds_per_policy=timings)
        io.save_json(run_dir / "metadata.json", meta)
        summary = summarise(exp, merged)
        io.save_json(run_dir / "summary.json", summary)
        _write_report(run_dir, exp, summary, meta)
    return run_dir


def fit_slope(t: np.ndarray, curves: np.ndarray, t_min: float, num_boot: int = 200,
              seed: int = 0) -> dict:
    """Log–log OLS slope of the seed-mean regret over t ≥ t_min, with a seed-bootstrap 95% CI."""
    mask = (t >= t_min) & (t > 0)
    if mask.sum() < 2:
        return {"slope": float("nan"), "lo": float("nan"), "hi": float("nan"), "t_min": t_min}
    lt = np.log(t[mask])

    def slope(mean_curve):
        y = np.log(np.maximum(mean_curve[mask], 1e-12))
        return float(np.polyfit(lt, y, 1)[0])

    rng = np.random.default_rng(seed)
    s = curves.shape[0]
    boots = [slope(curves[rng.integers(0, s, s)].mean(0)) for _ in range(num_boot)]
    return {"slope": slope(curves.mean(0)), "lo": float(np.percentile(boots, 2.5)),
            "hi": float(np.percentile(boots, 97.5)), "t_min": float(t_min)}


def summarise(exp: RegretExperiment, merged: dict) -> dict:
    """Per policy: final regret (mean, 95% CI, both definitions) and the fitted log–log slope;
    and SERN's α(T) with Theorem 1's c = e^{-1/α}/K and the exact π_min (``theorem1``)."""
    from sern_jax import schedules, theory

    t = merged["t"].astype(np.float64)
    alpha = float(schedules.alpha_of_horizon(exp.schedule, exp.horizon, exp.alpha0, exp.p))
    out = {"horizon": exp.horizon, "num_seeds": exp.num_seeds, "policies": {},
           # SERN's exploration floor for the figure (figures read results, never recompute)
           "theorem1": {"alpha": alpha, "c": float(theory.thm1_c(alpha, exp.num_arms)),
                        "pi_min": float(theory.thm1_pi_min(alpha, exp.num_arms))}}
    for policy in exp.policies:
        reg = merged[f"{policy}__regret_rb"].astype(np.float64)
        final = reg[:, -1]
        se = final.std(ddof=1) / np.sqrt(final.size) if final.size > 1 else float("nan")
        paper = merged[f"{policy}__regret_rb_paper"][:, -1].astype(np.float64)
        realised = merged[f"{policy}__regret"][:, -1].astype(np.float64)
        out["policies"][policy] = {
            "regret_T_mean": float(final.mean()),
            "regret_T_ci95": [float(final.mean() - 1.96 * se), float(final.mean() + 1.96 * se)],
            "regret_T_realised_mean": float(realised.mean()),
            "regret_paper_T_mean": float(paper.mean()),
            "regret_over_T": float(final.mean() / exp.horizon),
            "slope_last_decade": fit_slope(t, reg, t_min=max(1.0, exp.horizon / 10)),
            "min_prob": float(merged[f"{policy}__min_prob"][:, -1].min()),
        }
    return out


def _write_report(run_dir: Path, exp: RegretExperiment, summary: dict, meta: dict) -> None:
    lines = [
        "# Regret-curve run", "",
        f"Problem: K={exp.num_arms}, contexts={exp.num_contexts}, means={exp.means}, "
        f"estimator={exp.estimator}, T={exp.horizon}, seeds={exp.num_seeds}, "
        f"schedule={exp.schedule} (α0={exp.alpha0}, p={exp.p}), ε={exp.epsilon}, "
        f"root seed {exp.seed}.", "",
        "Regret is Rao–Blackwellised pseudo-regret, Σ_t (max_a r_a(s_t) − Σ_a π_t(a) r_a(s_t)),"
        " mean over seeds with a 95% CLT interval; the slope is the log–log OLS slope of the "
        "mean curve over the last decade of t, with a 95% seed-bootstrap interval (slope 1 = "
        "linear regret).", "",
        "| policy | R_T (mean) | 95% CI | R_T/T | paper's R_T | slope (last decade) |",
        "|---|---|---|---|---|---|",
    ]
    for policy, s in summary["policies"].items():
        sl = s["slope_last_decade"]
        lines.append(
            f"| {policy} | {s['regret_T_mean']:.2f} | [{s['regret_T_ci95'][0]:.2f}, "
            f"{s['regret_T_ci95'][1]:.2f}] | {s['regret_over_T']:.4f} | "
            f"{s['regret_paper_T_mean']:.2f} | {sl['slope']:.3f} [{sl['lo']:.3f}, {sl['hi']:.3f}] |")
    lines += ["", "Figures: `figures/regret.png` (regret vs T, log–log), "
              "`figures/exploration.png` (N_a(t)/t against the floor c = e^{-1/α}/K).", "",
              f"Made with sern_jax {meta['versions'].get('sern_jax')}, jax "
              f"{meta['versions'].get('jax')}, commit {meta.get('git_commit')}."]
    (run_dir / "report.md").write_text("\n".join(lines) + "\n")


class _nullcontext:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _progress_bar(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="seed", desc="regret", disable=not enabled,
                dynamic_ncols=True)
