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
import os
import shutil
import time
from pathlib import Path

import numpy as np

from sern_jax.infra import io

__all__ = ["RegretExperiment", "run_experiment", "compute_chunk", "summarise", "FIELDS"]

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
    # False: keep on-device summaries over seeds (executor.run_seeds(summary=True): means,
    # variances, min/max, histogram quantiles) instead of per-seed arrays
    per_seed: bool = True

    def fingerprint(self) -> str:
        """Hash of the fields that change results (not chunk size or devices)."""
        d = dataclasses.asdict(self)
        d.pop("chunk_size")
        d.pop("devices")
        if d["per_seed"]:  # the default keeps the fingerprints of runs made before the flag
            d.pop("per_seed")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _problem(exp: RegretExperiment, dtype):
    import jax

    from sern_jax.core import problems

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


_MAX_SEED = 2**32 - 1  # jax.random.key uses the seed modulo 2^32: larger ones would collide
_MAX_DAYS = 7.0  # refuse runs estimated to take longer than this on this machine
# Seed-rounds per second at K = 10, calibrated on two CPU cores: the fast softmax runner and
# the general runner (whose per-round cost grows with K); used only for the up-front estimate.
_FAST_RATE = 3.0e6
_GENERAL_RATE = 1.0e6


def check_integer(flag: str, value, low: int, high: int | None = None) -> None:
    """``value`` is an integer in [low, high] (no bool), or a ValueError naming ``flag``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low \
            or (high is not None and value > high):
        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{flag} must be an integer {rng}, got {value!r}")


def _check_cli_values(exp: RegretExperiment) -> None:
    """Checks of the raw option values (before any float32 cast hides them), naming the flag.

    ``--horizon`` is at most 2^24 in float32 (reward sums and counts stay exact integers) and
    2^31 − 1 with ``--float64`` (int32 round counters)."""
    if not exp.policies:
        raise ValueError("--policies is empty; give a comma list such as 'softmax,greedy'")
    from sern_jax.core import estimators, schedules as schedules_lib

    if exp.estimator not in estimators.ESTIMATOR_NAMES:
        raise ValueError(f"--estimator: unknown estimator {exp.estimator!r}; choose from "
                         f"{', '.join(estimators.ESTIMATOR_NAMES)} (or neural)")
    if exp.schedule not in schedules_lib.SCHEDULE_NAMES:
        raise ValueError(f"--schedule: unknown schedule {exp.schedule!r}; choose from "
                         f"{', '.join(schedules_lib.SCHEDULE_NAMES)}")
    if len(set(exp.policies)) != len(exp.policies):
        raise ValueError(f"--policies lists a policy twice: {','.join(exp.policies)}")
    check_integer("--arms", exp.num_arms, 2, 2**20)
    check_integer("--contexts", exp.num_contexts, 1, 2**20)
    check_integer("--seeds", exp.num_seeds, 1)
    check_integer("--horizon", exp.horizon, 1, 2**31 - 1 if exp.float64 else 2**24)
    check_integer("--checkpoints", exp.num_checkpoints, 1, 100_000)
    check_integer("--chunk-size", exp.chunk_size, 1)
    check_integer("--devices", exp.devices, 1)
    check_integer("--seed", exp.seed, 0, _MAX_SEED)
    for flag, value in (("--alpha", exp.alpha0), ("--p", exp.p), ("--epsilon", exp.epsilon),
                        ("--gap", exp.gap)):
        if not math.isfinite(value):
            raise ValueError(f"{flag} must be a finite number, got {value!r}")
    if exp.alpha0 <= 0:
        raise ValueError(f"--alpha must be > 0, got {exp.alpha0!r}")
    if not exp.float64:  # the run's float32 must hold them (1e300 would become inf; values
        # below its smallest normal are the α(T) check's, below)
        from sern_jax.infra import validate

        for flag, value in (("--alpha", exp.alpha0), ("--p", exp.p), ("--gap", exp.gap)):
            if abs(value) > validate.FLOAT32_MAX:
                raise ValueError(f"{flag} {value:g} is beyond float32's largest number "
                                 f"({validate.FLOAT32_MAX:.4g}): it would be computed as "
                                 "infinity; use --float64 or a smaller value")
    _check_means(exp)
    if not 0.0 <= exp.epsilon <= 1.0:
        raise ValueError(f"--epsilon must lie in [0, 1], got {exp.epsilon!r}")
    if exp.num_contexts > 1:
        if not 0.0 < exp.gap < 1.0:
            raise ValueError(f"--gap must lie in (0, 1), got {exp.gap!r}")
        if exp.means != RegretExperiment.means:
            raise ValueError(f"--means applies to one context; with --contexts "
                             f"{exp.num_contexts} the problem is random with gap --gap "
                             f"(got --means {exp.means!r})")
    if exp.schedule in ("log", "theorem4") and exp.p <= 0:
        raise ValueError(f"--p must be > 0 for --schedule {exp.schedule}, got {exp.p!r}")
    dtype = "float64" if exp.float64 else "float32"
    if "softmax" in exp.policies and exp.schedule in ("constant", "log", "theorem4") \
            and (exp.schedule == "constant" or exp.horizon >= 2):
        from sern_jax.core import schedules

        from sern_jax.infra import validate

        with validate.quiet_numerics():
            alpha = float(schedules.alpha_of_horizon(exp.schedule, exp.horizon, exp.alpha0,
                                                     exp.p))
        tiny = float(np.finfo(dtype).tiny)
        if not alpha >= tiny:
            hint = "use --float64 (down to 2.2e-308) or " if not exp.float64 else "use "
            raise ValueError(
                f"--alpha {exp.alpha0!r} gives the softmax temperature α(T) = {alpha:.3g}, "
                f"below the smallest normal {dtype} ({tiny:.3g}); {hint}the greedy policy "
                f"(the α → 0 limit)")


def _check_means(exp: RegretExperiment) -> None:
    """``--means``: 'linspace', 'random' or a comma list of K probabilities in [0, 1] (no
    empty item, no NaN), naming the flag."""
    if exp.means in ("linspace", "random") or exp.num_contexts > 1:
        return
    from sern_jax.infra import validate

    values = validate.comma_list_of(exp.means, "--means", float,
                                    "numbers (or 'linspace' or 'random')", unique=False)
    for v in values:
        if not 0.0 <= v <= 1.0:  # NaN fails too
            raise ValueError(f"--means: every success probability must lie in [0, 1], got "
                             f"{v!r}")
    if len(values) != exp.num_arms:
        raise ValueError(f"--means has {len(values)} values but --arms is {exp.num_arms}")


def _estimate(exp: RegretExperiment, triples) -> dict:
    """Up-front estimate of the run's memory, disk and time (host-side, no compile)."""
    from sern_jax.engine import drive as executor, fast_softmax

    out_bytes = 0
    seed_rounds_s = 0.0
    for _, cfg, params in triples:
        # summaries hold one chunk's outputs at a time, and save kilobytes per chunk
        kept = exp.num_seeds if exp.per_seed else min(exp.num_seeds, exp.chunk_size)
        out_bytes += kept * executor.bytes_per_seed(cfg)
        fast = fast_softmax.supports(cfg, params)
        rate = _FAST_RATE if fast else _GENERAL_RATE * min(1.0, 10.0 / exp.num_arms)
        seed_rounds_s += exp.num_seeds * exp.horizon / rate
    # merging holds every chunk and the concatenated arrays at once: twice the outputs
    return {"memory_bytes": 2 * out_bytes, "disk_bytes": 2 * out_bytes,
            "seconds": seed_rounds_s}




def check_fits(exp: RegretExperiment, triples, out_dir: Path) -> dict:
    """Refuses (``ValueError``, naming the estimate and the limit) runs that cannot fit."""
    est = _estimate(exp, triples)
    from sern_jax.engine import drive as executor

    avail = executor.available_memory_bytes()
    if est["memory_bytes"] > avail:
        raise ValueError(
            f"--seeds {exp.num_seeds} x {len(triples)} policies needs about "
            f"{io.fmt_bytes(est['memory_bytes'])} of memory to merge the results, more than the "
            f"{io.fmt_bytes(avail)} available; use fewer --seeds or --checkpoints")
    probe = out_dir
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if est["disk_bytes"] > free:
        raise ValueError(
            f"the run needs up to {io.fmt_bytes(est['disk_bytes'])} of disk under --out {out_dir}, "
            f"more than the {io.fmt_bytes(free)} free; use fewer --seeds or --checkpoints")
    if est["seconds"] > _MAX_DAYS * 86400:
        raise ValueError(
            f"--seeds {exp.num_seeds} x --horizon {exp.horizon} x {len(triples)} policies is "
            f"estimated at {io.fmt_time(est['seconds'])} on this machine, over the "
            f"{_MAX_DAYS:g}-day limit; use fewer --seeds or a shorter --horizon")
    return est


def _configs(exp: RegretExperiment):
    """Validated (policy, RunConfig, RunParams) triples; raises before any compile."""
    import jax.numpy as jnp

    from sern_jax.engine import simulate as sim

    _check_cli_values(exp)
    dtype = jnp.float64 if exp.float64 else jnp.float32
    for policy in exp.policies:  # names, sizes and dtype first: clearer errors
        sim.validate(sim.RunConfig(policy=policy, estimator=exp.estimator,
                                   schedule=exp.schedule, num_arms=exp.num_arms,
                                   horizon=exp.horizon, num_contexts=exp.num_contexts,
                                   num_checkpoints=exp.num_checkpoints,
                                   dtype="float64" if exp.float64 else "float32"))
    problem, random_means = _problem(exp, dtype)
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


def _chunk_name(policy: str, start: int, stop: int) -> str:
    """Chunk files are named by the seed range [start, stop) they hold, so a rerun with another
    --chunk-size or --devices can only reuse saved seeds, never mix two layouts."""
    return f"{policy}__seeds_{start:012d}-{stop:012d}.npz"


def _saved_ranges(chunk_dir: Path, policy: str) -> list[tuple[int, int, Path]]:
    out = []
    prefix = f"{policy}__seeds_"
    if not chunk_dir.is_dir():
        return out
    for path in chunk_dir.glob(f"{prefix}*.npz"):
        try:
            a, b = path.name[len(prefix):-len(".npz")].split("-")
            out.append((int(a), int(b), path))
        except ValueError:
            continue
    return sorted(out)


def _cover(saved, start: int, stop: int) -> list[tuple[int, int, Path]] | None:
    """Saved files (with the slice of each) that together hold seeds [start, stop), or None."""
    pieces, pos = [], start
    while pos < stop:
        best = max((s for s in saved if s[0] <= pos < s[1]), key=lambda s: s[1], default=None)
        if best is None:
            return None
        pieces.append((pos - best[0], min(best[1], stop) - best[0], best[2]))
        pos = min(best[1], stop)
    return pieces


def _load_range(saved, start: int, stop: int) -> dict[str, np.ndarray]:
    """Seeds [start, stop) of each field from the saved files, plus ``wall_s``: the seconds
    spent computing them (each file's time in proportion to the seeds taken from it)."""
    parts, wall = [], 0.0
    for lo, hi, path in _cover(saved, start, stop):
        data = io.load_npz(path)
        a, b = (int(v) for v in path.name.rsplit("_", 1)[1][:-4].split("-"))
        for f in FIELDS:
            if data[f].shape[0] != b - a:
                raise ValueError(f"{path} holds {data[f].shape[0]} rows of {f}, not the "
                                 f"{b - a} seeds its name says; delete it and rerun")
        parts.append({f: data[f][lo:hi] for f in FIELDS})
        if "wall_s" in data:
            wall += float(data["wall_s"]) * (hi - lo) / (b - a)
    out = {f: np.concatenate([p[f] for p in parts], axis=0) for f in FIELDS}
    out["wall_s"] = wall
    return out


def _runners(exp: RegretExperiment, triples, mesh) -> dict[str, str]:
    """The engine each policy ran on this host (``drive.plan_run``'s choice: ``fast``,
    ``thompson``, ``pallas`` or ``general``), recorded beside the results."""
    from sern_jax.engine import plan

    with _x64(exp):
        return {policy: plan.plan_run(cfg, params, exp.num_seeds, mesh=mesh).runner
                for policy, cfg, params in triples}


def run_experiment(exp: RegretExperiment, out_dir: str | Path, *, progress: bool = True,
                   log=print, ray=None) -> Path:
    """Runs (or resumes) the experiment into ``out_dir``; returns the run directory.

    Everything is validated (options, sizes against this machine's memory and disk, an
    existing directory's experiment, the device count) before anything is written; a run that
    fails before saving any seeds leaves no directory behind. ``ray``: a
    ``sern_jax.infra.distributed.RayConfig`` runs the missing seed chunks as Ray tasks (each writes
    its chunk file, as this process would: :func:`compute_chunk`); the same files result.
    """
    import jax

    run_dir = Path(out_dir)
    from sern_jax.infra import validate

    validate.out_dir(run_dir, "--out")  # tried for real, nothing left behind; before any jax
    ctx = jax.enable_x64() if exp.float64 else _nullcontext()
    with ctx:
        triples = _configs(exp)  # validation before any compile
        io.check_run_dir(run_dir, exp.fingerprint())  # refuses other settings' directory
        mesh = None
        if ray is not None and exp.devices > 1:
            raise ValueError("--devices: with --ray each task runs on one device (ask for "
                             "GPUs per task with --ray-gpus)")
        if exp.devices > 1:
            from sern_jax.infra.sharding import seed_mesh

            try:
                mesh = seed_mesh(exp.devices)
            except ValueError:
                raise ValueError(f"--devices {exp.devices}: only {len(jax.devices())} "
                                 f"device(s) visible") from None
        probe = run_dir
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir() or not os.access(probe, os.W_OK):
            raise ValueError(f"--out {run_dir}: cannot create the run directory there")
        est = check_fits(exp, triples, run_dir)
        if est["seconds"] > 60 and progress:
            log(f"estimated run time ~{io.fmt_time(est['seconds'])} "
                f"({io.fmt_bytes(est['memory_bytes'])} of results)")
        # created and locked in one step; a directory this run created is removed again,
        # under the lock, when it fails before saving any seeds (one writer per run directory)
        with io.run_lock(run_dir, remove_unused=no_chunks_saved):
            return _run(exp, triples, run_dir, mesh, progress, log, ray)


def no_chunks_saved(run_dir: Path) -> bool:
    """True when ``run_dir/chunks`` holds nothing (a run that saved no seeds)."""
    chunk_dir = run_dir / "chunks"
    return not (chunk_dir.is_dir() and any(chunk_dir.iterdir()))


def compute_chunk(exp: RegretExperiment, policy: str, start: int, stop: int, per_call: int,
                  chunk_dir: str, summary: bool = False, triples=None, mesh=None) -> None:
    """Seeds [start, stop) of ``policy``, saved atomically as their chunk file in
    ``chunk_dir``: the unit of work, the same call in this process and in a Ray task (which
    rebuilds ``triples`` from ``exp``). ``per_call``: seeds per compiled call (the caller's,
    so that every chunk of a run has one call shape)."""
    from sern_jax.engine import drive as executor

    with _x64(exp):
        if triples is None:
            triples = _configs(exp)
        _, cfg, params = next(t for t in triples if t[0] == policy)
        start_time = time.perf_counter()
        if summary:
            summ = executor.run_seeds(cfg, params, exp.seed, stop - start, first_seed=start,
                                      chunk_size=per_call, mesh=mesh, summary=True)
            io.save_npz(Path(chunk_dir) / _summary_chunk_name(policy, start, stop),
                        wall_s=np.float64(time.perf_counter() - start_time),
                        **executor.summary_arrays(summ))
            return
        out = executor.run_seeds(cfg, params, exp.seed, stop - start, first_seed=start,
                                 chunk_size=per_call, mesh=mesh)
        io.save_npz(Path(chunk_dir) / _chunk_name(policy, start, stop),
                    wall_s=np.float64(time.perf_counter() - start_time),
                    **{f: getattr(out, f) for f in FIELDS})


def _x64(exp: RegretExperiment):
    import jax

    return jax.enable_x64() if exp.float64 else _nullcontext()


def _ray_chunks(exp, todo, per_call: int, chunk_dir: Path, summary: bool, ray, run_dir: Path,
                progress: bool, log) -> None:
    """The missing chunks ``todo`` [(policy, start, stop)] as Ray tasks."""
    from sern_jax.infra import distributed

    name = _summary_chunk_name if summary else _chunk_name
    # an absolute path: a worker on another node does not start in this directory (the run
    # directory must be on a filesystem every node sees at the same path: docs/CLUSTER.md)
    units = [distributed.Unit(name(policy, a, b), compute_chunk,
                              (exp, policy, a, b, per_call, str(chunk_dir.resolve()), summary))
             for policy, a, b in todo]
    distributed.run_units(units, ray, run_dir, log=log, progress=progress, desc="chunks")


def _run(exp, triples, run_dir: Path, mesh, progress: bool, log=print, ray=None) -> Path:
    from sern_jax.engine import drive as executor
    from sern_jax.engine import simulate as sim

    (run_dir / "figures").mkdir(exist_ok=True)
    chunk_dir = run_dir / "chunks"
    chunk_dir.mkdir(exist_ok=True)
    # saved chunks are verified: a damaged one is set aside (<name>.damaged, logged
    # "damaged -> recomputing") and its seeds are computed again (they are deterministic)
    for path in sorted(chunk_dir.glob("*.npz")):
        io.npz_unit_done(path, log)
    io.save_json(run_dir / "config.json",
                 {"experiment": exp, "fingerprint": exp.fingerprint(),
                  "checkpoints": sim.checkpoint_times(triples[0][1])})
    chunk = min(exp.chunk_size, exp.num_seeds)
    ranges = [(a, min(a + chunk, exp.num_seeds)) for a in range(0, exp.num_seeds, chunk)]
    # one fixed call shape for every saved chunk (the last, smaller one too), split so that
    # each core runs its own calls
    per_call = math.ceil(chunk / executor.concurrent_calls(mesh))
    if not exp.per_seed:
        return _run_summaries(exp, triples, run_dir, mesh, progress, ranges, per_call, ray, log)
    if ray is not None:
        todo = [(policy, a, b) for policy, _, _ in triples for a, b in ranges
                if _cover(_saved_ranges(chunk_dir, policy), a, b) is None]
        _ray_chunks(exp, todo, per_call, chunk_dir, False, ray, run_dir, progress, log)
    bar = _progress_bar(len(triples) * exp.num_seeds, progress and ray is None)
    for policy, cfg, params in triples:
        for a, b in ranges:
            if _cover(_saved_ranges(chunk_dir, policy), a, b) is None:
                compute_chunk(exp, policy, a, b, per_call, str(chunk_dir), triples=triples,
                              mesh=mesh)
            bar.update(b - a)
    bar.close()
    merged, timings = {}, {}
    for policy, _, _ in triples:
        saved = _saved_ranges(chunk_dir, policy)
        parts = [_load_range(saved, a, b) for a, b in ranges]
        # compute time of every seed, whichever invocation (first run or resume) computed it
        timings[policy] = sum(p["wall_s"] for p in parts)
        for f in FIELDS:
            merged[f"{policy}__{f}"] = np.concatenate([p[f] for p in parts], axis=0)
    merged["t"] = sim.checkpoint_times(triples[0][1])
    merged["means"] = np.asarray(triples[0][2].problem.means)
    io.save_npz(run_dir / "results.npz", **merged)
    meta = io.run_metadata(wall_seconds_per_policy=timings,
                           runner_per_policy=_runners(exp, triples, mesh))
    io.save_json(run_dir / "metadata.json", meta)
    summary = summarise(exp, merged)
    io.save_json(run_dir / "summary.json", summary)
    _write_report(run_dir, exp, summary, meta)
    return run_dir


def _summary_chunk_name(policy: str, start: int, stop: int) -> str:
    return f"{policy}__summary_{start:012d}-{stop:012d}.npz"


def _run_summaries(exp, triples, run_dir: Path, mesh, progress: bool, ranges,
                   per_call: int, ray=None, log=print) -> Path:
    """``--no-per-seed``: each chunk of seeds is reduced on the device and saved as its
    summary (kilobytes); a rerun reuses the chunks of exactly the same seed ranges (another
    --chunk-size recomputes), and the chunks merge exactly in seed order (Chan et al.)."""
    from sern_jax.engine import drive as executor
    from sern_jax.engine import simulate as sim

    chunk_dir = run_dir / "chunks"
    if ray is not None:
        todo = [(policy, a, b) for policy, _, _ in triples for a, b in ranges
                if not (chunk_dir / _summary_chunk_name(policy, a, b)).exists()]
        _ray_chunks(exp, todo, per_call, chunk_dir, True, ray, run_dir, progress, log)
    bar = _progress_bar(len(triples) * exp.num_seeds, progress and ray is None)
    for policy, cfg, params in triples:
        for a, b in ranges:
            path = chunk_dir / _summary_chunk_name(policy, a, b)
            if not path.exists():
                compute_chunk(exp, policy, a, b, per_call, str(chunk_dir), summary=True,
                              triples=triples, mesh=mesh)
            bar.update(b - a)
    bar.close()
    merged, summaries, timings = {}, {}, {}
    for policy, _, _ in triples:
        parts, timings[policy] = [], 0.0
        for a, b in ranges:
            data = io.load_npz(chunk_dir / _summary_chunk_name(policy, a, b))
            part = executor.summary_from_arrays(data)
            if part.num_seeds != b - a:
                raise ValueError(f"{_summary_chunk_name(policy, a, b)} summarises "
                                 f"{part.num_seeds} seeds, not {b - a}; delete it and rerun")
            parts.append(part)
            timings[policy] += float(data["wall_s"]) if "wall_s" in data else 0.0
        summaries[policy] = executor.merge_summaries(parts)
        merged.update(executor.summary_arrays(summaries[policy], prefix=f"{policy}__"))
    merged["t"] = sim.checkpoint_times(triples[0][1])
    merged["means"] = np.asarray(triples[0][2].problem.means)
    io.save_npz(run_dir / "results.npz", **merged)
    meta = io.run_metadata(wall_seconds_per_policy=timings,
                           runner_per_policy=_runners(exp, triples, mesh))
    io.save_json(run_dir / "metadata.json", meta)
    summary = summarise_summaries(exp, summaries, merged["t"])
    io.save_json(run_dir / "summary.json", summary)
    _write_report(run_dir, exp, summary, meta)
    return run_dir


def summarise_summaries(exp: RegretExperiment, summaries: dict, t: np.ndarray) -> dict:
    """:func:`summarise` from on-device summaries (``--no-per-seed``): the same fields, the
    same Student-t interval (from the exact mean and variance); the slope of the mean curve
    has no interval (the bootstrap needs per-seed curves: ``lo``/``hi`` are NaN); adds the
    final regret's quantiles from the histograms with their guaranteed brackets."""
    from sern_jax.engine import drive as executor
    from sern_jax.core import schedules
    from sern_jax.analysis import stats, theory

    t = np.asarray(t, np.float64)
    alpha = float(schedules.alpha_of_horizon(exp.schedule, exp.horizon, exp.alpha0, exp.p))
    out = {"horizon": exp.horizon, "num_seeds": exp.num_seeds, "per_seed": False,
           "policies": {},
           "theorem1": {"alpha": alpha, "c": float(theory.thm1_c(alpha, exp.num_arms)),
                        "pi_min": float(theory.thm1_pi_min(alpha, exp.num_arms))}}
    for policy in exp.policies:
        s = summaries[policy]
        rb = s.regret_rb
        mean = float(rb.mean[-1])
        half = float(stats.t_half_width(float(rb.sd[-1]), rb.count, 0.95))
        curve = rb.mean.astype(np.float64)
        slope = fit_slope(t, curve[None, :], t_min=max(1.0, exp.horizon / 10), num_boot=0)
        quantiles = {}
        for q in executor.SUMMARY_QUANTILES:
            got = rb.quantile(q)
            quantiles[str(q)] = {"estimate": float(got.estimate[-1]), "lo": float(got.lo[-1]),
                                 "hi": float(got.hi[-1])}
        out["policies"][policy] = {
            "regret_T_mean": mean,
            "regret_T_ci95": [mean - half, mean + half],
            "regret_T_realised_mean": float(s.regret.mean[-1]),
            "regret_paper_T_mean": float(s.regret_rb_paper.mean[-1]),
            "regret_over_T": mean / exp.horizon,
            "slope_last_decade": slope,
            "min_prob": float(s.min_prob.min[-1]),
            "regret_T_sd": float(rb.sd[-1]),
            "regret_T_quantiles": quantiles,
        }
    return out


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

    if num_boot == 0:  # no per-seed curves: no interval
        return {"slope": slope(curves.mean(0)), "lo": float("nan"), "hi": float("nan"),
                "t_min": float(t_min)}
    rng = np.random.default_rng(seed)
    s = curves.shape[0]
    boots = [slope(curves[rng.integers(0, s, s)].mean(0)) for _ in range(num_boot)]
    return {"slope": slope(curves.mean(0)), "lo": float(np.percentile(boots, 2.5)),
            "hi": float(np.percentile(boots, 97.5)), "t_min": float(t_min)}


def summarise(exp: RegretExperiment, merged: dict) -> dict:
    """Per policy: final regret (mean, 95% CI, both definitions) and the fitted log–log slope;
    and SERN's α(T) with Theorem 1's c = e^{-1/α}/K and the exact π_min (``theorem1``)."""
    from sern_jax.core import schedules
    from sern_jax.analysis import stats, theory

    t = merged["t"].astype(np.float64)
    alpha = float(schedules.alpha_of_horizon(exp.schedule, exp.horizon, exp.alpha0, exp.p))
    out = {"horizon": exp.horizon, "num_seeds": exp.num_seeds, "policies": {},
           # SERN's exploration floor for the figure (figures read results, never recompute)
           "theorem1": {"alpha": alpha, "c": float(theory.thm1_c(alpha, exp.num_arms)),
                        "pi_min": float(theory.thm1_pi_min(alpha, exp.num_arms))}}
    for policy in exp.policies:
        reg = merged[f"{policy}__regret_rb"].astype(np.float64)
        final = reg[:, -1]
        ci = stats.t_interval(final, 0.95)  # Student t over seeds, n - 1 dof
        paper = merged[f"{policy}__regret_rb_paper"][:, -1].astype(np.float64)
        realised = merged[f"{policy}__regret"][:, -1].astype(np.float64)
        out["policies"][policy] = {
            "regret_T_mean": float(final.mean()),
            "regret_T_ci95": [ci.lower, ci.upper],
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
        " mean over seeds with a 95% Student-t interval (n − 1 dof); the slope is the log–log OLS slope of the "
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
    if summary.get("per_seed") is False:
        lines += ["", "Run with --no-per-seed: statistics over seeds were reduced on the device "
                  "(means and variances exact up to float rounding); the slope has no interval "
                  "(its bootstrap needs per-seed curves) and no figures are drawn. Quantiles of "
                  "R_T (histogram estimate [guaranteed bracket of the exact quantile]): "]
        for policy, s in summary["policies"].items():
            qs = ", ".join(f"q{float(q):g}: {v['estimate']:.2f} [{v['lo']:.2f}, {v['hi']:.2f}]"
                           for q, v in s["regret_T_quantiles"].items())
            lines.append(f"- {policy}: {qs}")
    else:
        lines += ["", "Figures: `figures/regret.png` (regret vs T, log–log), "
                  "`figures/exploration.png` (N_a(t)/t against the floor c = e^{-1/α}/K)."]
    lines += ["",
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
