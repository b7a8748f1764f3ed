"""``sern grasp learn --ray``: each object's learner copies as one unit of work.

The batched run (:func:`sern_jax.grasp.online.driver.run`) batches every (object, learner,
seed) copy of a run into one program per round. An object's copies depend on nothing
another object does: their keys are ``object_key(key(seed), name, s)`` (by the object's
name), their contexts, trials and learner updates are their own, and no step reduces over
objects. So the run splits into one *unit* per object, each the batched run of that object
alone, and joins back:

* a unit is :func:`run_unit`: ``driver.run(config, [spec], <out>/units/<unit>/)``, which
  writes its own ``checkpoint.npz`` after every round (atomically, ``io.save_npz``) and
  resumes from it; then ``unit.json`` (its timings and trial counts);
* :func:`run` (the driver) lists the units whose checkpoint is not finished, runs them as Ray
  tasks (:func:`sern_jax.infra.distributed.run_units`), and joins their checkpoints along the
  object axis into the run directory's ``checkpoint.npz``, the file a single-process run
  writes, with the same arrays (``tests/test_distributed.py`` compares them bit for bit on a
  local 2-CPU Ray). ``sern grasp learn`` then writes ``results.npz``, the tables and figures
  from it as it always does.

Resume. Rerun the same command: finished units are kept, unfinished ones resume from their
last round (the driver replays their updates). A run directory that a single-process run
left part-way (its ``checkpoint.npz`` at round r) is split into unit checkpoints at round r
first, so ``--ray`` continues it; a ``--ray`` run that stopped leaves the run directory's
checkpoint at the round every unit has passed, so the command without ``--ray`` continues
it too. A damaged unit checkpoint is set aside (``.damaged``) and its unit recomputed.

Faults: a unit that fails for good stops the run with one line naming the unit
(:class:`sern_jax.infra.distributed.UnitFailedError`); every unit's finished rounds are kept.

Results equal the single-process run's on the same backend: what one object's copies compute
does not depend on how many objects are batched beside them (checked bit for bit by the test
on XLA:CPU; a GPU driver against CPU tasks is another float program).
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from sern_jax.infra import io
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import checkpoint, driver
from sern_jax.grasp.online import config as config_lib
from sern_jax.grasp.world import objects as objects_lib

__all__ = ["UNITS_DIR", "run", "run_unit", "unit_dir", "unit_name"]

UNITS_DIR = "units"  # <run dir>/units/<unit>/: one object's run directory
_UNIT_JSON = "unit.json"


def unit_name(spec: objects_lib.ObjectSpec) -> str:
    """``object_<name>``; a name with characters other than letters, digits, ``.``, ``_``,
    ``-`` gets them replaced and its CRC32 appended (distinct names, distinct units)."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", spec.name)
    if safe != spec.name:
        safe += f"-{zlib.crc32(spec.name.encode()) & 0xFFFFFFFF:08x}"
    return f"object_{safe}"


def unit_dir(out_dir: str | Path, spec: objects_lib.ObjectSpec) -> Path:
    return Path(out_dir) / UNITS_DIR / unit_name(spec)


def run_unit(config: config_lib.OnlineConfig, spec: objects_lib.ObjectSpec, out_dir: str,
             theta0: artifacts.Theta0) -> None:
    """One unit (a Ray task): the batched run of object ``spec`` alone into ``out_dir``
    (resuming from its checkpoint), then ``unit.json`` with this call's timings and trial
    counts, written atomically."""
    res = driver.run(config, [spec], out_dir, theta0=theta0, progress=False,
                     log=lambda line: None)
    io.save_json(Path(out_dir) / _UNIT_JSON,
                 {"object": spec.name, "fingerprint": res["fingerprint"],
                  "timings": res["timings"], "trial_counts": res["trial_counts"]})


def _load_checkpoint(path: Path, fingerprint: str, what: str, log) -> dict | None:
    """A unit's checkpoint (None: missing, or damaged and set aside); another run's is an
    error naming it."""
    saved = io.load_npz_unit(path, log)
    if saved is not None and str(saved.get("fingerprint", "")) != fingerprint:
        raise ValueError(f"{path} holds a different learning run than {what}; delete "
                         f"{path.parent} (or choose another --out)")
    return saved


def _split(saved: dict, o: int, path: Path, fingerprint: str) -> None:
    """Unit ``o``'s checkpoint cut from a single-process run's (object axis 1)."""
    results = checkpoint.RoundResults(*(np.asarray(saved[f])[:, o:o + 1]
                                    for f in checkpoint.RoundResults._fields))
    rewards = np.asarray(saved["explore_reward"])[:, o:o + 1]
    path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint.save(path, fingerprint, results, rewards, int(saved["next_round"]))


def _join(unit_ckpts: list[dict]) -> tuple[checkpoint.RoundResults, np.ndarray, int]:
    """The run's arrays from its units' (object axis 1), at the round every unit passed."""
    next_round = min(int(s["next_round"]) for s in unit_ckpts)
    results = checkpoint.RoundResults(*(np.concatenate([np.asarray(s[f]) for s in unit_ckpts],
                                                   axis=1)
                                    for f in checkpoint.RoundResults._fields))
    rewards = np.concatenate([np.asarray(s["explore_reward"]) for s in unit_ckpts], axis=1)
    results, rewards = checkpoint.through(results, rewards, next_round)
    return results, rewards, next_round


def run(config: config_lib.OnlineConfig, specs: Sequence[objects_lib.ObjectSpec],
        out_dir: str | Path, *, theta0: artifacts.Theta0, ray, progress: bool = True,
        log: Callable[[str], None] = print) -> dict:
    """Runs (or resumes) the learning run with one Ray task per object; returns what
    :func:`driver.run` returns (``states`` None: the learner states stay in the tasks).

    Args:
      config, specs, theta0: as :func:`driver.run` (the default simulated world).
      out_dir: the run directory (the caller holds its lock).
      ray: a :class:`sern_jax.infra.distributed.RayConfig`.

    Raises:
      sern_jax.infra.distributed.UnitFailedError: a unit failed for good (one line); the run
        directory's checkpoint then holds the rounds every unit finished (when every unit
        has finished round 0; the units' own checkpoints are kept either way).
      ValueError: the run directory, or a unit's, holds another run; ``--backend mjx``
        without ``--ray-gpus`` (:func:`sern_jax.infra.distributed.check_backend`).
    """
    from sern_jax.infra import distributed

    distributed.check_backend(config.backend, ray)  # mjx tasks on a GPU only
    out_dir = Path(out_dir)
    names = [s.name for s in specs]
    if not names or len(set(names)) != len(names):
        raise ValueError(f"objects must be given and distinct, got {names}")
    fingerprint = config_lib.run_fingerprint(config, list(specs), theta0)
    num_r = config.rounds
    ckpt = out_dir / "checkpoint.npz"
    main = None
    if ckpt.exists():
        main = io.load_npz(ckpt, advice="delete it (or choose another --out) and rerun")
        if str(main.get("fingerprint", "")) != fingerprint:
            raise ValueError(f"{out_dir} holds a different learning run; choose another "
                             "--out or delete it")
    if main is not None and int(main["next_round"]) > num_r:  # finished: nothing to run
        results = checkpoint.RoundResults(*(main[f] for f in checkpoint.RoundResults._fields))
        return _outputs(config, names, fingerprint, results, {}, {"requested": 0,
                                                                  "simulated": 0}, {})
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [unit_dir(out_dir, s) / "checkpoint.npz" for s in specs]
    prints = [config_lib.run_fingerprint(config, [s], theta0) for s in specs]
    saved = [_load_checkpoint(p, f, out_dir, log) for p, f in zip(paths, prints)]
    if main is not None:  # a run started without --ray (or joined part-way): its units
        for o, (path, unit) in enumerate(zip(paths, saved)):
            if unit is None or int(unit["next_round"]) < int(main["next_round"]):
                _split(main, o, path, prints[o])
    saved = [_load_checkpoint(p, f, out_dir, log) for p, f in zip(paths, prints)]
    todo = [o for o, s in enumerate(saved) if s is None or int(s["next_round"]) <= num_r]
    for p in (unit_dir(out_dir, specs[o]) / _UNIT_JSON for o in todo):
        p.unlink(missing_ok=True)  # unit.json: this call's figures only
    log(f"learn: {len(specs)} objects as units ({UNITS_DIR}/object_*); "
        f"{len(specs) - len(todo)} already done")
    next_round = 0
    try:
        reports = distributed.run_units(
            [distributed.Unit(unit_name(specs[o]), run_unit,
                              (config, specs[o], str(paths[o].parent.resolve()), theta0))
             for o in todo], ray, out_dir, log=log, progress=progress, desc="objects")
    finally:  # finished rounds of every unit -> the run's checkpoint (also on failure)
        saved = [_load_checkpoint(p, f, out_dir, log) for p, f in zip(paths, prints)]
        if all(s is not None for s in saved):
            results, rewards, next_round = _join(saved)
            if main is None or next_round > int(main["next_round"]):
                checkpoint.save(ckpt, fingerprint, results, rewards, next_round)
    if next_round <= num_r:  # a unit returned unfinished: a bug, never a partial table
        raise RuntimeError(f"--ray: the units stopped before round {num_r} finished (the "
                           f"slowest at round {next_round - 1}); rerun to resume")
    timings: dict[str, float] = {}
    counts = {"requested": 0, "simulated": 0}
    for o in todo:
        doc = io.load_json(unit_dir(out_dir, specs[o]) / _UNIT_JSON)
        for k, v in doc["timings"].items():
            timings[k] = timings.get(k, 0.0) + float(v)
        for k in counts:
            counts[k] += int(doc["trial_counts"].get(k, 0))
    return _outputs(config, names, fingerprint, results, timings, counts, reports)


def _outputs(config, names, fingerprint, results, timings, counts, reports) -> dict:
    """What :func:`driver.run` returns for a finished run, from the joined arrays."""
    rows = checkpoint.table_rows(names, config.policies, results.paper_eval,
                             results.lowvar_eval if config.eval_poses else None,
                             results.pseudo_regret if config.regret_trials else None)
    return {"table": rows, "results": results, "timings": timings, "trial_counts": counts,
            "objects": names, "fingerprint": fingerprint, "config": config, "states": None,
            "units": reports}
