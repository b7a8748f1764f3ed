"""SERN against the exploration strategies the field uses now, at the same grasp budget:
every registered learner on the shipped hard set, the paper's rounds.

    python -m experiments.grasp_baselines bench              # round time per learner vs sern
    python -m experiments.grasp_baselines tune   --out DIR   # main knobs, on other objects
    python -m experiments.grasp_baselines run    --out DIR   # the comparison (20 seeds)
    python -m experiments.grasp_baselines summarize --out DIR
    python -m experiments.grasp_baselines merge --out DIR --merge-from NEW  # rerun learners

All learners share θ0, the core set, the update (40 Adam steps on D ∪ C after each phase of
20 grasps) and the budget (R = 5 rounds of 20 exploration + 5 evaluation grasps), and, within
a seed, the poses, candidate sets, inverse-CDF uniforms and trial noise (common random
numbers: differences are paired by seed).

Fair tuning (``tune``): each learner's main knob takes the same number of settings
(:data:`GRID`, three each, the paper's/default value among them) on objects that are not among
the six reported (:func:`tuning_objects`: the next three objects of the shipped screen's
hard-set order, i.e. the non-reported objects whose fresh-trial best candidate succeeds at
least 80 % with the lowest θ0 greedy success; read from the screen of the θ0 in use, so a new
trial's screen picks its own); the setting with the highest mean low-variance greedy success
over rounds 1..R (mean over tuning objects and seeds; ties: the first setting listed) is kept.
``greedy`` and ``normalized`` have no knob (one setting). Every tuning score, and the
per-seed figures behind them (``tune_per_seed.npz``), are saved.

Per learner (``summarize``, from the saved per-seed results only): successes during
exploration (what a robot owner pays for), final low-variance greedy success, per-round
pseudo-regret (when ``--regret-trials`` > 0); paired differences against SERN over seeds
(each seed's value is the mean over the six objects), Student-t intervals (n − 1 dof) and
Holm's correction over the comparisons of each metric (``sern_jax.analysis.stats``).

Resuming. Every run directory's checkpoint holds the results and rewards only (kilobytes;
the runner replays the learners' updates on resume), so a comparison stopped by a device
command's time limit resumes from the files it left: rerun the same command with the same
``--out`` (``tune`` skips settings whose run finished; ``run`` resumes its run directory).
``collect`` writes ``per_seed.npz`` and the summary from whatever rounds have finished.

Files under ``--out``: ``tune/setting<i>/`` and ``run/`` (the runner's run directories, each
a ``checkpoint.npz``), ``tuned.json`` (every tuning score and the choice),
``tune_per_seed.npz``, ``per_seed.npz`` (the reported run's per-seed figures,
[R + 1, O, Q, S]), ``meta.json``, ``summary.json``, ``table.md``;
``figures/make_grasp_baselines_fig.py`` draws from them.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

NUM_TUNING_OBJECTS = 3
REFERENCE = "sern"
# learner -> (hyperparameter field, three settings); the default / paper value is among them
GRID = {
    "sern": ("alpha", (0.02, 0.05, 0.1)),
    "sern_log": ("alpha0", (0.07, 0.28, 1.0)),  # α = α0/ln(T^p) = 0.05, 0.2, 0.72 at T = 100
    "sern_decay": ("decay_alpha0", (0.05, 0.1, 0.2)),
    "egreedy": ("epsilon", (0.05, 0.1, 0.2)),
    "egreedy_decay": ("decay_epsilon0", (0.5, 1.0, 2.0)),
    "neural_linucb": ("ucb_width", (0.25, 1.0, 4.0)),
    "neural_lints": ("lambda_prior", (0.05, 0.25, 1.25)),  # prior variance σ²/λ
    # shared heads (the default layout since the rerun): the default 3, the earlier
    # comparison's 5 (whole networks, tuned over 2, 3, 5), Bootstrapped DQN's K = 10
    "ensemble_ts": ("ensemble_size", (3, 5, 10)),
    "neural_ucb": ("nu", (0.1, 1.0, 10.0)),
}
NO_KNOB = ("greedy", "normalized")
# Hyperparameters added after runs were recorded, with the value those runs used (their
# meta.json lacks the field): ensemble_ts ran M whole networks before --ensemble-heads.
FORMER_DEFAULTS = {"ensemble_ts": {"ensemble_heads": "networks"}}
_CONFIG_FIELDS = ("alpha", "epsilon", "alpha0", "p")  # OnlineConfig's own fields
DEFAULT_OUT = Path("experiments/results/grasp_baselines")


def learners() -> tuple[str, ...]:
    from sern_jax.learners import registry

    return registry.names()


def online_config(policies, values: dict, **kw):
    """An OnlineConfig with learner hyperparameters ``values`` (field name -> value)."""
    from sern_jax.grasp.online import config as config_lib

    own = {k: v for k, v in values.items() if k in _CONFIG_FIELDS}
    hyper = {k: v for k, v in values.items() if k not in _CONFIG_FIELDS}
    return config_lib.OnlineConfig(policies=tuple(policies), hyper=hyper, **own, **kw)


def _specs(names):
    from sern_jax.grasp.world import objects as objects_lib

    return [objects_lib.make_object(n) for n in names]


def tuning_objects(theta0, num: int = NUM_TUNING_OBJECTS) -> list[str]:
    """The ``num`` objects tuning runs on: the next ``num`` of the shipped screen's hard-set
    order after the six reported (``artifacts.hard_set``: objects whose best candidate
    succeeds >= 80 % on fresh trials, by θ0 greedy success), never a reported object; if
    too few qualify, the remaining screened objects of lowest θ0 greedy success."""
    from sern_jax.grasp.model import artifacts

    reported = artifacts.hard_set(theta0)["objects"]
    ordered = artifacts.hard_set(theta0, len(reported) + num)["objects"]
    chosen = [n for n in ordered if n not in reported][:num]
    rest = sorted((r for r in theta0.screen["objects"]
                   if r["object"] not in reported and r["object"] not in chosen),
                  key=lambda r: (r["greedy_success"], r["object"]))
    chosen += [r["object"] for r in rest][:num - len(chosen)]
    return chosen


def hard_specs():
    """The shipped hard set's specs (the six reported objects) and θ0."""
    from sern_jax.grasp.model import artifacts

    theta0 = artifacts.load_theta0()
    return _specs(artifacts.hard_set(theta0)["objects"]), theta0


def _run(config, specs, out_dir, theta0, progress):
    from sern_jax.grasp.online import driver

    t = time.perf_counter()
    res = driver.run(config, specs, out_dir, theta0=theta0, progress=progress)
    return res, time.perf_counter() - t


# ----------------------------------------------------------------------------- tune


def tune_setting(i: int, knobbed: tuple[str, ...], objects: list[str], seeds: int,
                 rounds: int, explore: int, backend: str, run_dir: str) -> None:
    """Setting ``i`` of the GRID, run into ``run_dir``: the unit of ``tune --ray`` (the
    same ``driver.run`` call that :func:`tune` makes, which then reads the finished run
    back)."""
    from sern_jax.grasp.model import artifacts

    values = {GRID[n][0]: GRID[n][1][i] for n in knobbed}
    config = online_config(knobbed, values, num_seeds=seeds, rounds=rounds, explore=explore,
                           backend=backend)
    _run(config, _specs(objects), Path(run_dir), artifacts.load_theta0(), False)


def tune(out: Path, seeds: int, rounds: int, backend: str, progress: bool,
         num_objects: int = NUM_TUNING_OBJECTS, explore: int = 20,
         names: tuple[str, ...] | None = None, ray=None) -> dict:
    """Runs the GRID's settings on :func:`tuning_objects`; writes and returns ``tuned.json``
    (and ``tune_per_seed.npz``: low-variance success [setting, R + 1, O, Q, S]). A setting
    whose run directory holds a finished run is read back, not rerun (resume). ``ray``
    (``sern_jax.infra.distributed.RayConfig``): the three settings run as Ray tasks first
    (:func:`tune_setting`), and are then read back; ``wall_s`` is then the tasks' time."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts

    theta0 = artifacts.load_theta0()
    objects = tuning_objects(theta0, num_objects)
    hard = set(artifacts.hard_set(theta0)["objects"])
    if hard & set(objects):
        raise SystemExit(f"tuning objects {sorted(hard & set(objects))} are reported")
    specs = _specs(objects)
    knobbed = tuple(n for n in (names or learners()) if n in GRID)
    scores = {n: [] for n in knobbed}
    wall, lowvars, explores = [], [], []
    reports = {}
    if ray is not None:
        import importlib

        from sern_jax.infra import distributed

        # the module by its package name (not __main__), which every worker imports
        mod = importlib.import_module(__spec__.name if __spec__ else __name__)
        reports = distributed.run_units(
            [distributed.Unit(f"tune/setting{i}", mod.tune_setting,
                              (i, knobbed, objects, seeds, rounds, explore, backend,
                               str((out / "tune" / f"setting{i}").resolve())))
             for i in range(3)], ray, out, progress=False, desc="settings")
    for i in range(3):
        values = {GRID[n][0]: GRID[n][1][i] for n in knobbed}
        config = online_config(knobbed, values, num_seeds=seeds, rounds=rounds,
                               explore=explore, backend=backend)
        res, secs = _run(config, specs, out / "tune" / f"setting{i}", theta0, progress)
        wall.append(reports.get(f"tune/setting{i}", {}).get("seconds", secs))
        lowvar = np.asarray(res["results"].lowvar_eval)  # [R + 1, O, Q, S]
        lowvars.append(lowvar)
        explores.append(np.asarray(res["results"].explore_success))
        for q, n in enumerate(config.policies):
            scores[n].append(float(lowvar[1:, :, q, :].mean()))
    choice = {n: GRID[n][1][int(np.argmax(scores[n]))] for n in knobbed}
    np.savez_compressed(out / "tune_per_seed.npz",
                        lowvar_eval=np.stack(lowvars).astype(np.float32),
                        explore_success=np.stack(explores).astype(np.float32))
    doc = {"objects": objects, "seeds": seeds, "rounds": rounds, "explore": explore,
           "learners": list(knobbed),
           "rule": ("tuning objects: the next objects of the shipped screen's hard-set "
                    "order after the six reported (artifacts.hard_set), none reported"),
           "criterion": ("mean low-variance greedy success over rounds 1..R, tuning "
                         "objects and seeds; ties: the first setting listed"),
           "grid": {n: {"field": GRID[n][0], "settings": list(GRID[n][1]),
                        "scores": scores[n], "chosen": choice[n]} for n in knobbed},
           "no_knob": list(NO_KNOB), "wall_s": wall,
           "resolution": None,
           "axes": "tune_per_seed.npz: [setting, R + 1, O, Q (learners), S]",
           "machine": io.machine(),
           "command": "python -m experiments.grasp_baselines tune " + " ".join(sys.argv[2:])}
    doc["resolution"] = tuning_resolution(np.stack(lowvars), doc)
    (out / "tuned.json").write_text(json.dumps(doc, indent=1, default=str))
    return doc


def tuning_resolution(lowvar: np.ndarray, doc: dict, level: float = 0.95,
                      power: float = 0.8) -> dict:
    """How informative a tuning was: per knobbed learner, the chosen setting minus the
    runner-up (the setting of the second-highest score) on the tuning criterion, paired
    over the tuning seeds (each seed's value: mean over rounds 1..R and the tuning
    objects; the settings share seeds, i.e. random numbers), Student-t intervals and Holm
    over the learners (``stats.paired_differences``), and the seeds a paired t-test would
    need to resolve the observed difference at the observed per-seed SD (two-sided, normal
    approximation, ``level`` and ``power``).

    Args:
      lowvar: ``tune_per_seed.npz``'s ``lowvar_eval`` [setting, R + 1, O, Q, S].
      doc: ``tuned.json`` (its ``learners`` give Q's order, ``grid`` the scores).
    """
    from scipy import stats as sps

    from sern_jax.analysis import stats

    names = list(doc["learners"])
    per_seed = lowvar[:, 1:].mean(axis=(1, 2))  # [setting, Q, S]
    rows, diffs = {}, []
    for q, name in enumerate(names):
        scores = np.asarray(doc["grid"][name]["scores"])
        order = np.argsort(-scores, kind="stable")  # ties: the first setting listed
        best, second = int(order[0]), int(order[1])
        diffs.append(per_seed[best, q] - per_seed[second, q])
        rows[name] = {"chosen": best, "runner_up": second}
    paired = stats.paired_differences(np.stack(diffs), names=names, level=level)
    z = sps.norm.ppf(1 - (1 - level) / 2) + sps.norm.ppf(power)
    for name, d in zip(names, paired):
        need = int(np.ceil((z * d.sd / abs(d.mean)) ** 2)) if d.mean and d.sd else None
        rows[name].update(mean=float(d.mean), sd=float(d.sd), lower=float(d.lower),
                          upper=float(d.upper), pvalue=float(d.pvalue),
                          pvalue_holm=float(d.pvalue_holm), resolved=bool(d.resolved),
                          seeds_for_power=need)
    return {"level": level, "power": power, "num_seeds": int(lowvar.shape[-1]),
            "what": ("chosen minus runner-up setting, paired over tuning seeds (mean over "
                     "rounds 1..R and objects), t interval, Holm over learners; "
                     "seeds_for_power: seeds a paired t-test needs at this difference and "
                     "per-seed SD"),
            "learners": rows}


def tuned_values(out: Path, untuned: bool) -> dict:
    """Field name -> value for the reported run: the tuned choice, or the defaults."""
    if untuned:
        return {}
    path = out / "tuned.json"
    if not path.exists():
        raise SystemExit(f"{path} is missing: run `tune` first, or pass --untuned")
    doc = json.loads(path.read_text())
    return {g["field"]: g["chosen"] for g in doc["grid"].values()}


# ----------------------------------------------------------------------------- run


class DifferentRunError(ValueError):
    """``run``'s run directory holds another run (one line; ``main`` exits 2)."""


def check_run_dir(out: Path, run_dir: Path, config, specs, theta0) -> dict | None:
    """Refuses (:class:`DifferentRunError`) a run directory holding another run, before
    ``meta.json`` is touched (the runner, or learn_units, would refuse it only after
    ``meta.json`` was rewritten with these settings): its ``checkpoint.npz`` (a single-process
    run's, or a ``--ray`` run's join) and each reported object's ``units/object_*/
    checkpoint.npz`` (what a ``--ray`` run leaves, also when it stopped before any join)
    must carry the fingerprint these settings give (``config.run_fingerprint`` of the whole
    run, or of that object alone). Unit folders of objects not in ``specs`` are ignored (the
    runner never reads them). Returns the run's checkpoint (None if there is none)."""
    from sern_jax.infra import io
    from sern_jax.grasp.online import config as config_lib
    from sern_jax.grasp.online import learn_units

    advice = "delete it (or choose another --out) and rerun"
    mixed = (f"--out {out}: {run_dir} holds a different learning run than these settings; "
             "choose another --out (or --run-dir) or delete it")
    ckpt = run_dir / "checkpoint.npz"
    saved = io.load_npz(ckpt, advice=advice) if ckpt.exists() else None
    if saved is not None and (str(saved.get("fingerprint", ""))
                              != config_lib.run_fingerprint(config, specs, theta0)):
        raise DifferentRunError(mixed)
    # The fingerprint holds the hyperparameters given, not the defaults, so a learner
    # whose default changed (ensemble_ts: --ensemble-heads networks -> shared) has the same
    # fingerprint under both: the learners' configs meta.json recorded must match too.
    recorded = out / "meta.json"
    if saved is not None and recorded.exists():
        before = json.loads(recorded.read_text()).get("learner_configs", {})
        for name in (n for n in config.policies if n in before):  # recorded learners
            was = {**FORMER_DEFAULTS.get(name, {}), **before[name]}
            now = dataclasses.asdict(config.learner_config(name))
            for field in sorted(set(was) & set(now)):
                if was[field] != now[field]:
                    raise DifferentRunError(
                        f"--out {out}: {run_dir} holds a run whose {name} had {field} = "
                        f"{was[field]!r} (meta.json), these settings give {now[field]!r} "
                        "(a default changed since); choose another --out")
    for spec in specs:
        unit = learn_units.unit_dir(run_dir, spec) / "checkpoint.npz"
        if not unit.exists():
            continue
        got = str(io.load_npz(unit, advice=advice).get("fingerprint", ""))
        if got != config_lib.run_fingerprint(config, [spec], theta0):
            raise DifferentRunError(mixed.replace(
                f"{run_dir} holds", f"{unit.parent} (a --ray unit of {run_dir}) holds"))
    return saved


def run(out: Path, seeds: int, rounds: int, regret_trials: int, backend: str, untuned: bool,
        num_objects: int | None, progress: bool, explore: int = 20,
        run_dir: Path | None = None, regret_grasps: int = 0,
        names: tuple[str, ...] | None = None, ray=None) -> None:
    """The reported comparison. ``meta.json`` is written first and ``per_seed.npz`` from the
    runner's checkpoint, so a run stopped after some rounds still leaves its finished rounds
    (``collect``); ``run_dir`` (default ``out/run``) is the runner's run directory (a
    checkpoint of kilobytes): the same command resumes it. ``ray``
    (``sern_jax.infra.distributed.RayConfig``): one Ray task per object
    (``sern_jax.grasp.online.learn_units``: ``run_dir/units/``, joined into the same checkpoint)."""
    from sern_jax.infra import io

    specs, theta0 = hard_specs()
    specs = specs[:num_objects] if num_objects else specs
    values = tuned_values(out, untuned)
    config = online_config(names or learners(), values, num_seeds=seeds, rounds=rounds,
                           explore=explore, regret_trials=regret_trials,
                           regret_grasps=regret_grasps, backend=backend)
    run_dir = run_dir or out / "run"
    saved = check_run_dir(out, run_dir, config, specs, theta0)
    out.mkdir(parents=True, exist_ok=True)
    meta = io.run_metadata(
        experiment="grasp_baselines", objects=[s.name for s in specs],
        learners=list(config.policies), reference=REFERENCE,
        hyperparameters=config.hyperparameters(), tuned=not untuned, num_seeds=seeds,
        learner_configs={n: dataclasses.asdict(config.learner_config(n))
                         for n in config.policies},
        rounds=rounds, explore=config.explore, evaluate=config.evaluate,
        eval_poses=config.eval_poses, eval_trials=config.eval_trials,
        regret_trials=regret_trials, regret_grasps=config.regret_grasps, backend=backend,
        run_dir=str(run_dir), checkpoints=True,
        command="python -m experiments.grasp_baselines run " + " ".join(sys.argv[2:]),
        theta0_fingerprint=theta0.fingerprint,
        physics=_physics_settings(),
        axes="[R + 1, O, Q, S]: round (0 = θ0), object, learner, seed")
    # One entry per invocation (a comparison may take several short runs): when
    # it started, from which round, and (if it ended) its wall time, timings and trials.
    previous = out / "meta.json"
    calls = json.loads(previous.read_text()).get("calls", []) if previous.exists() else []
    start = int(saved["next_round"]) if saved is not None else 0
    call = {"started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "start_round": start, "host": meta["host"], "jax": meta.get("jax"),
            "finished": False}
    meta["calls"] = calls + [call]
    (out / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
    if ray is None:
        res, secs = _run(config, specs, run_dir, theta0, progress)
    else:  # the same checkpoint, each object's copies a Ray task
        from sern_jax.grasp.online import learn_units

        t = time.perf_counter()
        res = learn_units.run(config, specs, run_dir, theta0=theta0, ray=ray,
                              progress=progress)
        secs = time.perf_counter() - t
    call.update(finished=True, wall_s=secs, timings=res["timings"],
                trial_counts=res["trial_counts"])
    meta.update(wall_s=sum(c.get("wall_s", 0.0) for c in meta["calls"]),
                fingerprint=res["fingerprint"])
    (out / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
    collect(out)


def _physics_settings():
    from sern_jax.grasp.world import sim

    fn = getattr(sim, "physics_settings", None)  # the trial (force, frictions, schedule)
    return fn() if fn else None


PER_SEED_FIELDS = ("paper_eval", "lowvar_eval", "explore_success", "pseudo_regret")


class MergeError(ValueError):
    """``merge``: the runs cannot be joined (one line; ``main`` exits 2, nothing written)."""


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit for bit (NaN equal to NaN: unfinished rounds, no regret accounting)."""
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


def collect(out: Path) -> None:
    """``per_seed.npz`` from the run directory's checkpoint (the finished rounds only; a
    stopped run records ``rounds_completed`` in meta.json), then :func:`summarize`.

    A merged comparison (:func:`merge`; ``meta["merged"]``) takes each merged learner's
    slices from its own run's checkpoint (``out/<merged run_dir>/checkpoint.npz``), after
    checking that run's reference learner equals the main run's bit for bit."""
    from sern_jax.infra import io

    meta = json.loads((out / "meta.json").read_text())
    run_dir = Path(meta["run_dir"])
    if not (run_dir / "checkpoint.npz").exists():  # made elsewhere (a device's $OUT)
        run_dir = out / "run"
    saved = io.load_npz(run_dir / "checkpoint.npz")
    done = int(saved["next_round"])  # rounds 0 .. done - 1 are finished
    if done < 2:
        raise SystemExit(f"only {done} round(s) finished: nothing to compare")
    per_seed = {f: np.asarray(saved[f])[:done] for f in PER_SEED_FIELDS}
    for part in meta.get("merged", []):
        other = io.load_npz(out / part["run_dir"] / "checkpoint.npz")
        if int(other["next_round"]) != int(saved["next_round"]):
            raise MergeError(f"{part['run_dir']}: finished {int(other['next_round']) - 1} "
                             f"rounds, the main run {done - 1}")
        names, src = meta["learners"], part["source_learners"]
        q_ref, p_ref = names.index(REFERENCE), src.index(REFERENCE)
        for f in PER_SEED_FIELDS:
            theirs = np.asarray(other[f])[:done]
            if not _same(theirs[:, :, p_ref], per_seed[f][:, :, q_ref]):
                raise MergeError(f"{part['run_dir']}: its {REFERENCE} {f} differs from the "
                                 f"main run's: the learners' results are not independent of "
                                 f"the run they are in; rerun every learner together")
            for name in part["learners"]:
                per_seed[f][:, :, names.index(name)] = theirs[:, :, src.index(name)]
    np.savez_compressed(out / "per_seed.npz",
                        **{f: v.astype(np.float32) for f, v in per_seed.items()})
    meta["rounds_completed"] = done - 1
    (out / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
    summarize(out)


# Settings that must agree between a comparison and a run merged into it.
_MERGE_SAME = ("objects", "num_seeds", "rounds", "explore", "evaluate", "eval_poses",
               "eval_trials", "regret_trials", "regret_grasps", "backend",
               "theta0_fingerprint", "physics", "reference")


def merged_tuning(out: Path, new: Path, replaced) -> tuple[dict, dict]:
    """``tuned.json`` and ``tune_per_seed.npz`` of ``out`` with the ``replaced`` learners'
    tuning taken from ``new`` (a ``tune --policies sern,<learners>`` into another --out),
    the earlier choice kept under ``replaced``; nothing written. Refused (``MergeError``)
    unless the tuning objects, seeds, rounds, explore and criterion agree and the reference
    learner's tuning per-seed figures are equal bit for bit (what :func:`merge` checks; the
    rerun comparison of all learners reads such a file as its tuning)."""
    tuned, tuned_new = (json.loads((d / "tuned.json").read_text()) for d in (out, new))
    tps, tps_new = (dict(np.load(d / "tune_per_seed.npz")) for d in (out, new))
    for key in ("objects", "seeds", "rounds", "explore", "criterion"):
        if tuned.get(key) != tuned_new.get(key):
            raise MergeError(f"--merge-from {new}: tuning {key} differs")
    q_ref, p_ref = tuned["learners"].index(REFERENCE), tuned_new["learners"].index(REFERENCE)
    for f in tps:
        if not _same(tps_new[f][:, :, :, p_ref], tps[f][:, :, :, q_ref]):
            raise MergeError(f"--merge-from {new}: {REFERENCE}'s tuning {f} differs from "
                             "the comparison's: rerun every learner's tuning together")
    for name in replaced:
        q, p = tuned["learners"].index(name), tuned_new["learners"].index(name)
        for f in tps:
            tps[f][:, :, :, q] = tps_new[f][:, :, :, p]
        tuned.setdefault("replaced", {})[name] = {
            **tuned["grid"][name], "why": "rerun with another default (merge)",
            "tune_per_seed": "the earlier tune_per_seed.npz, in git history"}
        tuned["grid"][name] = tuned_new["grid"][name]
    tuned["merged"] = {"learners": list(replaced), "command": tuned_new.get("command"),
                       "machine": tuned_new.get("machine"), "wall_s": tuned_new.get("wall_s"),
                       "reference_tuning_identical": True}
    tuned["resolution"] = tuning_resolution(tps["lowvar_eval"], tuned)
    return tuned, tps


def merge(out: Path, new: Path) -> dict:
    """Replaces learners of the comparison in ``out`` by their rerun in ``new`` (a ``tune``
    and ``run`` of ``--policies sern,<learners>`` into another --out, e.g. with a new
    default), keeping every other learner's results. Valid only if a learner's per-seed
    results do not depend on which learners run beside it (keys per object and seed, trials
    shared only where choices coincide, a trial independent of its batch): checked on the
    reference learner, whose per-seed figures in ``new`` must equal ``out``'s bit for bit in
    every field and round (and in tuning: its tuning scores per seed), else nothing is
    written (``MergeError``). Writes ``out/run_<learners>/checkpoint.npz`` (the rerun's
    checkpoint; ``run/`` is kept), ``meta.json`` (the learners' configs and
    hyperparameters, and ``merged``: which learners came from which run, its command,
    calls and code), ``tuned.json`` / ``tune_per_seed.npz`` (the learners' tuning replaced,
    the earlier one kept under ``replaced``), then :func:`collect` (per-seed file, summary,
    table)."""
    from sern_jax.infra import io

    meta, meta_new = (json.loads((d / "meta.json").read_text()) for d in (out, new))
    for key in _MERGE_SAME:
        if meta.get(key) != meta_new.get(key):
            raise MergeError(f"--merge-from {new}: {key} differs ({meta_new.get(key)!r}, "
                             f"the comparison's {meta.get(key)!r})")
    src = list(meta_new["learners"])
    replaced = [n for n in src if n != REFERENCE]
    if REFERENCE not in src or not replaced or not set(replaced) <= set(meta["learners"]):
        raise MergeError(f"--merge-from {new}: its learners {src} must be {REFERENCE} and "
                         f"learners of the comparison {meta['learners']}")
    if meta_new["learner_configs"][REFERENCE] != meta["learner_configs"][REFERENCE]:
        raise MergeError(f"--merge-from {new}: {REFERENCE}'s hyperparameters differ")
    tuned, tps = merged_tuning(out, new, replaced)
    run_name = "run_" + "_".join(replaced)
    ckpt = io.load_npz(new / "run" / "checkpoint.npz")
    # the reference learner's results are compared before anything is written
    main_dir = Path(meta["run_dir"])
    if not (main_dir / "checkpoint.npz").exists():  # made elsewhere (a device's $OUT)
        main_dir = out / "run"
    main_ckpt = io.load_npz(main_dir / "checkpoint.npz")
    if int(ckpt["next_round"]) != int(main_ckpt["next_round"]):
        raise MergeError(f"--merge-from {new}: finished {int(ckpt['next_round']) - 1} "
                         f"rounds, the comparison {int(main_ckpt['next_round']) - 1}")
    for f in PER_SEED_FIELDS + ("explore_action", "explore_reward"):
        mine = np.asarray(main_ckpt[f])
        mine = mine[:, :, meta["learners"].index(REFERENCE)] if f != "explore_reward" \
            else mine[..., meta["learners"].index(REFERENCE), :]
        theirs = np.asarray(ckpt[f])
        theirs = theirs[:, :, src.index(REFERENCE)] if f != "explore_reward" \
            else theirs[..., src.index(REFERENCE), :]
        if not _same(theirs, mine):
            raise MergeError(f"--merge-from {new}: its {REFERENCE} {f} differs from the "
                             "comparison's: rerun every learner together")
    (out / run_name).mkdir(exist_ok=True)
    io.save_npz(out / run_name / "checkpoint.npz", **ckpt)
    for name in replaced:
        meta["learner_configs"][name] = meta_new["learner_configs"][name]
    for field, value in meta_new["hyperparameters"].items():
        if field in {GRID[n][0] for n in replaced if n in GRID}:
            meta["hyperparameters"][field] = value
    np.savez_compressed(out / "tune_per_seed.npz", **tps)
    (out / "tuned.json").write_text(json.dumps(tuned, indent=1, default=str))
    meta.setdefault("merged", []).append({
        "learners": replaced, "source_learners": src, "run_dir": run_name,
        "reference_identical": f"{REFERENCE}'s per-seed {', '.join(PER_SEED_FIELDS)} and "
                               "tuning scores equal the main run's bit for bit",
        **{k: meta_new.get(k) for k in ("command", "calls", "git_commit", "created",
                                        "versions", "host", "jax", "wall_s",
                                        "learner_configs", "hyperparameters")}})
    (out / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
    collect(out)
    return meta


# ----------------------------------------------------------------------------- summary


def per_seed_metrics(per_seed: dict, meta: dict) -> dict:
    """Per learner, per seed (mean over objects): metric -> [Q, S]."""
    explore = per_seed["explore_success"][1:]  # [R, O, Q, S]
    lowvar = per_seed["lowvar_eval"]
    out = {
        "explore_success": explore.mean(axis=(0, 1)),  # fraction of exploration grasps
        "final_lowvar": lowvar[-1].mean(axis=0),
        "paper_eval_mean": per_seed["paper_eval"][1:].mean(axis=(0, 1)),
    }
    regret = per_seed["pseudo_regret"][1:]
    if meta.get("regret_trials") and np.isfinite(regret).all():
        # expected successes lost per round of E exploration grasps (mean over rounds)
        out["pseudo_regret_per_round"] = regret.mean(axis=(0, 1))
    return out


def summarize(out: Path) -> dict:
    """summary.json and table.md from per_seed.npz and meta.json (nothing recomputed)."""
    from sern_jax.analysis import stats

    per_seed = dict(np.load(out / "per_seed.npz"))
    meta = json.loads((out / "meta.json").read_text())
    names = meta["learners"]
    ref = names.index(REFERENCE)
    others = [i for i in range(len(names)) if i != ref]
    metrics = per_seed_metrics(per_seed, meta)
    summary = {"learners": names, "objects": meta["objects"], "num_seeds": meta["num_seeds"],
               "rounds": int(per_seed["lowvar_eval"].shape[0] - 1),
               "rounds_planned": meta["rounds"], "reference": REFERENCE, "level": 0.95,
               "intervals": ("Student t over seeds (n - 1 dof), each seed = mean over the "
                             "objects; Holm over the comparisons of each metric"),
               "metrics": {}}
    for metric, values in metrics.items():
        diffs = stats.paired_differences(values[others], values[ref],
                                         names=[f"{names[i]} - {REFERENCE}" for i in others])
        ci = stats.t_interval(values, 0.95)
        summary["metrics"][metric] = {
            "mean": {n: float(ci.mean[q]) for q, n in enumerate(names)},
            "sd": {n: float(ci.sd[q]) for q, n in enumerate(names)},
            "se": {n: float(ci.se[q]) for q, n in enumerate(names)},
            "paired": [d._asdict() for d in diffs],
        }
    if "pseudo_regret_per_round" in metrics:
        pr = per_seed["pseudo_regret"][1:].mean(axis=1)  # [R, Q, S], mean over objects
        by_round = {}
        for q, n in enumerate(names):
            ci = stats.t_interval(pr[:, q], 0.95, axis=1)
            by_round[n] = {k: [float(v) for v in getattr(ci, k)]
                           for k in ("mean", "se", "lower", "upper")}
        summary["pseudo_regret_by_round"] = by_round
        summary["pseudo_regret_oracle"] = {
            "regret_trials": meta.get("regret_trials"),
            "regret_grasps": meta.get("regret_grasps") or meta.get("explore"),
            "explore": meta.get("explore"),
            "what": ("expected successes lost to the oracle's best candidate (argmax of "
                     "regret_trials trials per candidate, valued on as many independent "
                     "ones) per round of explore grasps, under the learner's own "
                     "distribution; estimated on the first regret_grasps grasps of each "
                     "phase and scaled by explore / regret_grasps")}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "table.md").write_text(table_md(summary))
    print(table_md(summary))
    return summary


def table_md(summary: dict) -> str:
    names = summary["learners"]
    head = (f"Learners vs {summary['reference']} on {', '.join(summary['objects'])}; "
            f"{summary['num_seeds']} seeds; {summary['rounds']} of "
            f"{summary['rounds_planned']} rounds; {summary['intervals']}.")
    lines = [head, ""]
    for metric, m in summary["metrics"].items():
        scale = 100.0 if metric != "pseudo_regret_per_round" else 1.0
        unit = "%" if scale == 100.0 else ""
        header = (f"| learner | mean ± SE{unit and ' (%)'} | − {summary['reference']} "
                  "(95 % t CI) | p (Holm) | resolved |")
        lines += [f"### {metric}", "", header, "|---|---|---|---|---|"]
        paired = {p["name"].split(" - ")[0]: p for p in m["paired"]}
        for n in names:
            row = f"| {n} | {scale * m['mean'][n]:.1f} ± {scale * m['se'][n]:.1f} |"
            p = paired.get(n)
            if p is None:
                row += " (reference) | | |"
            else:
                row += (f" {scale * p['mean']:+.1f} [{scale * p['lower']:+.1f}, "
                        f"{scale * p['upper']:+.1f}] | {p['pvalue_holm']:.3g} | "
                        f"{'yes' if p['resolved'] else 'no'}"
                        f"{' (sd 0: every seed the same)' if p['sd'] == 0 else ''} |")
            lines.append(row)
        lines.append("")
    if "pseudo_regret_by_round" in summary:
        by_round = summary["pseudo_regret_by_round"]
        num_r = len(next(iter(by_round.values()))["mean"])
        orc = summary.get("pseudo_regret_oracle", {})
        lines += ["### pseudo-regret per round", "",
                  f"Expected successes lost per round of {orc.get('explore')} exploration "
                  f"grasps (oracle: {orc.get('regret_trials')} + {orc.get('regret_trials')} "
                  f"independent trials per candidate, on {orc.get('regret_grasps')} grasps "
                  "per phase, scaled); mean [95 % t interval] over seeds.", "",
                  "| learner | " + " | ".join(f"round {r + 1}" for r in range(num_r)) + " |",
                  "|---|" + "---|" * num_r]
        for n in names:
            b = by_round[n]
            lines.append(f"| {n} | " + " | ".join(
                f"{b['mean'][r]:.2f} [{b['lower'][r]:.2f}, {b['upper'][r]:.2f}]"
                for r in range(num_r)) + " |")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- bench


def parse_bench_learners(text: str | None) -> list[tuple[str, str, dict]]:
    """``bench --learners``: comma-separated entries ``name`` or ``name:field=value:...``
    (a learner at other hyperparameters, e.g. ``ensemble_ts:ensemble_size=5``) ->
    [(label, name, values)]; a value is read as int, else float, else kept as text.
    Bad names or values: ``ValueError`` naming ``--learners``."""
    from sern_jax.learners import registry

    if not text:
        return [(n, n, {}) for n in registry.names()]
    out = []
    for entry in text.split(","):
        name, *pairs = entry.split(":")
        registry.check_names((name,), "--learners")
        values = {}
        for pair in pairs:
            field, eq, raw = pair.partition("=")
            if not eq:
                raise ValueError(f"--learners: {pair!r} in {entry!r} is not field=value")
            for cast in (int, float, str):
                try:
                    values[field] = cast(raw)
                    break
                except ValueError:
                    continue
        known = {f.name for f in dataclasses.fields(registry.LEARNERS[name].config)}
        for field in values:
            if field not in known:
                raise ValueError(f"--learners: {name} has no hyperparameter {field!r}; "
                                 f"known: {', '.join(sorted(known)) or 'none'}")
        registry.make_config(name, values)  # a bad value names its flag
        out.append((entry, name, values))
    labels = [e[0] for e in out]
    if len(set(labels)) != len(labels):
        raise ValueError(f"--learners: entries must not repeat, got {text}")
    return out


def bench(copies: tuple[int, int], repeats: int, names=None) -> dict:
    """Time of one round's learner work for every learner, in this process, compiles
    excluded, on the shipped θ0 network and core set with O × S copies: ``act`` over a
    phase of E = 20 grasps as the runner runs it without regret accounting (no π output,
    ``act_s``) and with it (π output, ``act_probs_s``), ``update``, and greedy on the
    5 + 4 evaluation poses. Contexts, crops and trials are shared by the learners and not
    timed. Learners are interleaved: each repeat times every learner once, in an order
    rotated by one each repeat, so slow drifts of a shared machine's load hit all; every
    repeat's wall and process-CPU seconds are kept, and ``vs_sern`` ratios are given per
    repeat (same repeat's SERN) with their median, min and max.

    ``names``: labels of :func:`parse_bench_learners` (``ensemble_ts:ensemble_size=5``)."""
    import os

    import jax
    import jax.numpy as jnp

    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.online import config as config_lib
    from sern_jax.grasp.online import step
    from sern_jax.learners import base as lbase
    from sern_jax.learners import registry

    entries = parse_bench_learners(",".join(names) if names else None)
    theta0 = artifacts.load_theta0()
    model = config_lib.quality_model(config_lib.copies_network(theta0.network.config))
    core = config_lib.core_data("dpp", theta0)
    config = config_lib.OnlineConfig(policies=("sern",))
    train = config.train_config()
    num_o, num_s = copies
    e, k, n_eval = config.explore, 64, config.evaluate + config.eval_poses
    rng = np.random.default_rng(0)
    idx = rng.integers(0, core.reward.shape[0], (num_o, num_s, e, k))
    image = jnp.asarray(np.asarray(core.inputs[0])[idx])
    depth = jnp.asarray(np.asarray(core.inputs[1])[idx])
    valid = jnp.asarray(rng.random((num_o, num_s, e, k)) < 0.9)
    u = jnp.asarray(rng.random((num_o, num_s, e)), jnp.float32)
    keys = jax.vmap(lambda o: jax.vmap(lambda s: jax.random.fold_in(
        jax.random.fold_in(jax.random.key(0), o), s))(jnp.arange(num_s)))(jnp.arange(num_o))
    pick = jax.vmap(jax.vmap(jax.vmap(lambda x, i: x[i])))
    load_start = os.getloadavg()
    work, configs = {}, {}
    t_compile = time.perf_counter()
    for label, name, values in entries:
        lconf = registry.make_config(name, {**config.hyperparameters(), **values})
        configs[label] = (name, dataclasses.asdict(lconf))
        lrn = registry.make(name, model, train, lconf)
        state = step.batched_init(lrn.init)(keys, theta0.params, core)
        act = step.batched_act(lrn.act, False)  # the run without regret accounting
        act_probs = step.batched_act(lrn.act, True)  # with it (π is output)
        update = step.batched_update(lrn.update)
        greedy = step.batched_greedy(step.predict_fn(lrn, model))

        def timed(state=state, act=act, act_probs=act_probs, update=update, greedy=greedy):
            """[wall, cpu] seconds of (act, act with π, update, greedy)."""
            rows = []

            def clock(fn):
                t, c = time.perf_counter(), time.process_time()
                out = jax.block_until_ready(fn())
                rows.append((time.perf_counter() - t, time.process_time() - c))
                return out

            action, _ = clock(lambda: act(keys, state, image, depth, valid, u, jnp.int32(0)))
            clock(lambda: act_probs(keys, state, image, depth, valid, u, jnp.int32(0)))
            a = jnp.maximum(action, 0)
            batch = lbase.Batch((pick(image, a), pick(depth, a)), action,
                                jnp.ones(action.shape, jnp.float32))
            new = clock(lambda: update(keys, state, batch))
            clock(lambda: greedy(new, image[:, :, :n_eval], depth[:, :, :n_eval],
                                 valid[:, :, :n_eval], u[:, :, :n_eval]))
            return np.asarray(rows)  # [4, 2]

        timed()  # compile
        work[label] = (timed, [])
    t_compile = time.perf_counter() - t_compile
    labels = [label for label, _, _ in entries]
    for r in range(repeats):
        shift = r % len(labels)
        for label in labels[shift:] + labels[:shift]:
            timed, rows = work[label]
            rows.append(timed())
    parts = ("act", "act_probs", "update", "greedy")
    out = {"machine": io.machine(), "load_average_start": list(load_start),
           "load_average_end": list(os.getloadavg()), "copies": [num_o, num_s],
           "explore": e, "candidates": k, "eval_poses_per_round": n_eval,
           "repeats": repeats, "compile_and_first_call_s": t_compile,
           "train": dataclasses.asdict(train), "jax": jax.__version__,
           "fields": ("act_s: act over a phase as the runner runs it without regret "
                      "accounting (no π output); act_probs_s: with π (regret on); "
                      "round_s = act_s + update_s + greedy_s (the paper setting); "
                      "round_regret_s = act_probs_s + update_s + greedy_s; each the median "
                      "over repeats; *_cpu_s the same in process CPU seconds (all threads); "
                      "vs_sern: round_s / sern's round_s (medians); vs_sern_per_repeat: "
                      "each repeat's ratio to the same repeat's sern; times: per repeat "
                      "[act, act_probs, update, greedy] x [wall, cpu] seconds"),
           "learners": {}}
    for label in labels:
        rows = np.asarray(work[label][1])  # [repeats, 4, 2]
        name, lconf = configs[label]
        row = {"learner": name, "config": lconf}
        for j, part in enumerate(parts):
            row[f"{part}_s"] = float(np.median(rows[:, j, 0]))
            row[f"{part}_cpu_s"] = float(np.median(rows[:, j, 1]))
        for suffix, col in (("s", 0), ("cpu_s", 1)):
            row[f"round_{suffix}"] = float(np.median(rows[:, [0, 2, 3], col].sum(1)))
            row[f"round_regret_{suffix}"] = float(np.median(rows[:, 1:, col].sum(1)))
        row["times"] = rows.tolist()
        out["learners"][label] = row
    if REFERENCE in work:
        ref = np.asarray(work[REFERENCE][1])
        for label in labels:
            rows = np.asarray(work[label][1])
            row = out["learners"][label]
            row["vs_sern"] = row["round_s"] / out["learners"][REFERENCE]["round_s"]
            row["vs_sern_cpu"] = (row["round_cpu_s"]
                                  / out["learners"][REFERENCE]["round_cpu_s"])
            row["vs_sern_regret"] = (row["round_regret_s"]
                                     / out["learners"][REFERENCE]["round_regret_s"])
            per = rows[:, [0, 2, 3], 0].sum(1) / ref[:, [0, 2, 3], 0].sum(1)
            per_cpu = rows[:, [0, 2, 3], 1].sum(1) / ref[:, [0, 2, 3], 1].sum(1)
            row["vs_sern_per_repeat"] = per.tolist()
            row["vs_sern_cpu_per_repeat"] = per_cpu.tolist()
            for key, v in (("vs_sern", per), ("vs_sern_cpu", per_cpu)):
                row[f"{key}_median"] = float(np.median(v))
                row[f"{key}_min"], row[f"{key}_max"] = float(v.min()), float(v.max())
    return out


def record_learn_timing(run_dir: Path, summary_json: Path, time_file: Path) -> dict:
    """One JSON from a timed ``sern grasp learn`` (``paper_all_learners_2core.json``): its
    ``--json-out`` file (wall seconds, machine at the end), the run directory's
    ``metadata.json`` (versions, commit, timings, trial counts) and ``config.json``, and
    ``/usr/bin/time -v -o TIME_FILE``'s CPU seconds, elapsed time and peak memory."""
    import re

    out = json.loads(Path(summary_json).read_text())
    meta = json.loads((Path(run_dir) / "metadata.json").read_text())
    cfg = json.loads((Path(run_dir) / "config.json").read_text())
    text = Path(time_file).read_text()

    def field(name):
        m = re.search(re.escape(name) + r":\s*(.+)", text)
        if m is None:
            raise SystemExit(f"{time_file} has no '{name}' line (not /usr/bin/time -v output)")
        return m.group(1).strip()

    return {"what": ("a timed sern grasp learn: wall seconds from its --json-out, CPU from "
                     "/usr/bin/time -v"),
            "command": "/usr/bin/time -v -o " + str(time_file) + " "
                       + field("Command being timed").strip('"'),
            "seconds": out["seconds"], "machine_at_end": out["machine"],
            "git_commit": meta.get("git_commit"), "versions": meta.get("versions"),
            "timings": meta.get("timings"), "trial_counts": meta.get("trial_counts"),
            "user_cpu_s": float(field("User time (seconds)")),
            "system_cpu_s": float(field("System time (seconds)")),
            "percent_cpu": field("Percent of CPU this job got"),
            "elapsed": field("Elapsed (wall clock) time (h:mm:ss or m:ss)"),
            "max_rss_kb": int(field("Maximum resident set size (kbytes)")),
            "config": cfg.get("config")}


def main(argv=None) -> None:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    p = validate.script_parser(__spec__, description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("bench", "tune", "run", "collect", "summarize",
                                    "record-learn", "merge"))
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--tune-seeds", type=int, default=4)
    p.add_argument("--tune-rounds", type=int, default=3, help="tune: rounds per setting")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--explore", type=int, default=20, help="grasps per exploration phase")
    p.add_argument("--objects", type=validate.int_at_least(1), default=None,
                   help="first N of the hard set")
    p.add_argument("--regret-trials", type=int, default=0,
                   help="run: oracle trials per candidate (x2: selection and valuation)")
    p.add_argument("--regret-grasps", type=int, default=0,
                   help="run: oracle on the first G grasps of each phase (0: all)")
    p.add_argument("--backend", choices=("native", "mjx"), default="native")
    p.add_argument("--untuned", action="store_true", help="run with every default")
    p.add_argument("--copies", default="6,5", help="bench: O,S parameter copies")
    p.add_argument("--repeats", type=int, default=5, help="bench: timed rounds per learner")
    p.add_argument("--learners", default=None,
                   help="bench: comma-separated learners, each NAME or "
                        "NAME:field=value[:field=value] (e.g. ensemble_ts:ensemble_size=5)")
    p.add_argument("--json-out", type=Path, default=None, help="bench: write the JSON here")
    p.add_argument("--run-dir", type=Path, default=None,
                   help="run: the runner's run directory (default OUT/run; large)")
    p.add_argument("--results-only", action="store_true",
                   help="(kept for old commands: every checkpoint is now results only)")
    p.add_argument("--policies", default=None,
                   help="run: comma-separated learners (default: every registered one)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--learn-run", type=Path, default=None,
                   help="record-learn: a timed `sern grasp learn` run directory; its "
                        "--json-out file and /usr/bin/time -v -o file are DIR.json and "
                        "DIR.time beside it (written to --json-out)")
    p.add_argument("--merge-from", type=Path, default=None,
                   help="merge: a tune + run of --policies sern,<learners> (its --out) whose "
                        "learners replace the comparison's in --out (sern must be equal bit "
                        "for bit)")
    from sern_jax.infra import distributed

    distributed.add_arguments(p)  # --ray: tune's settings, run's objects as tasks
    a = p.parse_args(argv)
    try:  # Ray refusals: one line, exit 2
        ray = distributed.from_args(a)
        if ray is not None and a.what not in ("tune", "run"):
            raise ValueError("--ray applies to tune (its three settings are the units) and "
                             "run (its objects are)")
        distributed.check_backend(a.backend, ray)  # mjx tasks on a GPU only
    except ValueError as e:
        p.exit(2, f"{p.prog}: error: {e}\n")
    for flag, v in (("--seeds", a.seeds), ("--tune-seeds", a.tune_seeds),
                    ("--rounds", a.rounds), ("--tune-rounds", a.tune_rounds),
                    ("--repeats", a.repeats), ("--explore", a.explore)):
        if v < (2 if flag in ("--seeds", "--tune-seeds") else 1):
            p.error(f"{flag} must be >= {2 if 'seeds' in flag else 1}, got {v}")
    if a.regret_trials < 0:
        p.error(f"--regret-trials must be >= 0, got {a.regret_trials}")
    if not 0 <= a.regret_grasps <= a.explore:
        p.error(f"--regret-grasps must be in [0, --explore], got {a.regret_grasps}")
    names = None
    if a.policies:
        from sern_jax.learners import registry

        try:
            names = registry.check_names(a.policies.split(","), "--policies")
        except ValueError as e:
            p.error(str(e))
        if REFERENCE not in names:
            p.error(f"--policies must include the reference {REFERENCE!r}")
    if a.what == "bench":
        try:
            o, s = (int(v) for v in a.copies.split(","))
            if o < 1 or s < 1:
                raise ValueError
        except ValueError:
            p.error(f"--copies must be O,S with two integers >= 1, got {a.copies!r}")
        try:
            parse_bench_learners(a.learners)
        except ValueError as e:
            p.error(str(e))
        res = bench((o, s), a.repeats, a.learners.split(",") if a.learners else None)
        res["command"] = "python -m experiments.grasp_baselines " + " ".join(
            sys.argv[1:] if argv is None else argv)
        text = json.dumps(res, indent=1)
        print(text)
        if a.json_out:
            a.json_out.parent.mkdir(parents=True, exist_ok=True)
            a.json_out.write_text(text)
    elif a.what == "tune":
        a.out.mkdir(parents=True, exist_ok=True)
        try:
            doc = tune(a.out, a.tune_seeds, a.tune_rounds, a.backend, not a.no_progress,
                       explore=a.explore, num_objects=a.objects or NUM_TUNING_OBJECTS,
                       names=names, ray=ray)
        except distributed.UnitFailedError as e:  # one line naming the setting
            raise SystemExit(str(e)) from None
        print(json.dumps(doc, indent=1))
    elif a.what == "run":
        try:
            run(a.out, a.seeds, a.rounds, a.regret_trials, a.backend, a.untuned, a.objects,
                not a.no_progress, a.explore, a.run_dir, a.regret_grasps, names, ray=ray)
        except distributed.UnitFailedError as e:  # one line naming the object
            raise SystemExit(str(e)) from None
        except DifferentRunError as e:  # nothing written
            p.exit(2, f"{p.prog}: error: {e}\n")
    elif a.what == "record-learn":
        if a.learn_run is None or a.json_out is None:
            p.error("record-learn needs --learn-run DIR and --json-out FILE")
        run_dir = a.learn_run
        for f in (run_dir / "metadata.json", run_dir.with_suffix(".json"),
                  run_dir.with_suffix(".time")):
            if not f.exists():
                p.error(f"--learn-run: {f} is missing")
        doc = record_learn_timing(run_dir, run_dir.with_suffix(".json"),
                                  run_dir.with_suffix(".time"))
        a.json_out.parent.mkdir(parents=True, exist_ok=True)
        a.json_out.write_text(json.dumps(doc, indent=1, default=str))
        print(json.dumps({k: doc[k] for k in ("seconds", "user_cpu_s", "system_cpu_s",
                                              "trial_counts")}))
    elif a.what == "merge":
        if a.merge_from is None:
            p.error("merge needs --merge-from DIR")
        for d, flag in ((a.out, "--out"), (a.merge_from, "--merge-from")):
            for f in ("meta.json", "tuned.json", "tune_per_seed.npz"):
                if not (d / f).exists():
                    p.error(f"{flag}: {d / f} is missing")
        if not (a.merge_from / "run" / "checkpoint.npz").exists():
            p.error(f"--merge-from: {a.merge_from / 'run' / 'checkpoint.npz'} is missing")
        try:
            merge(a.out, a.merge_from)
        except MergeError as e:  # nothing written
            p.exit(2, f"{p.prog}: error: {e}\n")
    elif a.what == "collect":
        collect(a.out)
    else:
        summarize(a.out)


if __name__ == "__main__":
    main()
