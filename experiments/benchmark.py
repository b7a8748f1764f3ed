"""The grasp-exploration benchmark's record: per-seed files and summary.json from its parts.

    python -m experiments.benchmark summarise --runs RUN_DIR [RUN_DIR ...] \\
        --screen SCREEN.json [--benchmark NAME|FILE.json] [--reference sern] \\
        --out experiments/results/benchmark
    python -m experiments.benchmark summarise --out experiments/results/benchmark
    python -m experiments.benchmark power --sd-seed 2,3.5 --sd-object 1 --objects 12 \\
        --seeds 40 --family 4

A benchmark runs in parts, each a ``sern grasp learn`` run directory (``config.json`` and the
finished run's ``results.npz``, ``RoundResults`` [R + 1, O, Q, S]) holding some of the
benchmark's objects and learners. ``summarise --runs`` reads the parts, joins them into one
grid (every object × learner exactly once; the same seeds, rounds, exploration grasps,
evaluation and θ0 in every part, so a seed shares its random numbers across parts: the keys
depend on the object's name and the seed index only), and writes under ``--out``:

* ``per_seed/<object>.npz``: ``learners`` [Q], the raw ``lowvar_eval`` and
  ``explore_success`` [R + 1, Q, S] (fractions; round 0 = θ0) and each metric
  ``metric_<name>`` [Q, S] (``sern_jax.analysis.benchmark_stats.run_metrics``);
* ``meta.json``: the benchmark's name and version, the objects, learners, protocol, θ0, the
  parts it read and the screen's rows of the objects (``--screen``: the JSON of
  ``sern grasp screen --json-out``, fresh-trial rows);
* ``summary.json``: the comparisons of ``--reference`` against every other learner (objects
  as a random factor, Student t over the object means, Holm within the primary and the
  secondary family, TOST at ± 2 points), the per-object intervals of the forest plot, each
  learner's means, the learning curves and the screen, computed from ``meta.json`` and the
  per-seed files alone.

``summarise --out DIR`` without ``--runs`` recomputes ``summary.json`` from the files under
DIR (no run directory needed); ``figures/benchmark.py`` draws from ``summary.json``.
``power`` prints the detectable difference at 80 % power of the object-level test
(``benchmark_stats.detectable_difference``) for the pre-registration.

Bad input (a missing or unfinished part, an object or learner twice, parts that disagree,
an object without a screen row): one line naming the flag, exit 2, nothing written.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

__all__ = ["collect", "summarise_record", "load_record", "write_record", "summarise",
           "power_table", "main"]

# settings every part must share (the protocol; the learners' own knobs may differ per part)
PROTOCOL = ("num_seeds", "rounds", "explore", "evaluate", "eval_poses", "eval_trials",
            "fit_steps", "batch_size", "learning_rate", "loss", "core_set", "seed")
RAW = ("lowvar_eval", "explore_success")
CONVENTIONS = {
    "units": ("success rates in percent; differences in percentage points, except "
              "grasps_to_80 (exploration grasps)"),
    "pairing": ("differences a − b are paired per seed: within a seed every learner sees the "
                "same poses, candidates and trial noise (common random numbers)"),
    "intervals": ("comparisons: objects as a random factor, each object's mean paired "
                  "difference over its seeds, then a two-sided 95 % Student-t interval over "
                  "the object means (objects − 1 degrees of freedom) and the matching "
                  "two-sided t test of a zero difference; per_object: a two-sided 95 % "
                  "Student-t interval over that object's seeds (seeds − 1 degrees of "
                  "freedom); learner_means and curves: mean over objects of the objects' "
                  "means over seeds, SE (and t half-width) over the object means"),
    "holm": ("holm_p is Holm-adjusted within its family: primary = the two primary metrics "
             "× every other learner, secondary = the two secondary metrics × every other "
             "learner; a comparison is resolved when holm_p < 0.05"),
    "tost": ("equivalence by two one-sided t tests on the object-level difference at "
             "± margin points (objects − 1 degrees of freedom): p = max(p_lower, p_upper), "
             "equivalent when p < 0.05; grasps_to_80 has no margin (fields null)"),
    "grasps_to_80": ("exploration grasps (explore × the first round whose fixed-pose greedy "
                     "success is at least 80 %); a seed that never reaches it is censored at "
                     "(rounds + 1) × explore, so a mean with censored seeds is a lower bound"),
    "curve_area": "mean over rounds 1..R of the fixed-pose greedy success",
    "explore_success": ("mean over rounds 1..R of the fraction of exploration grasps that "
                        "succeeded (the bandit's own reward)"),
    "round5": "the fixed-pose greedy success after the last round",
    "per_seed_files": "paths relative to the folder holding summary.json",
}


def _bs():
    from sern_jax.analysis import benchmark_stats

    return benchmark_stats


# ----------------------------------------------------------------------------- reading parts


def _read_part(path: Path) -> dict:
    from sern_jax.infra import io, validate

    flag = f"--runs {path}"
    if not path.is_dir():
        raise ValueError(f"{flag}: not a directory")
    if not (path / "config.json").is_file():
        raise ValueError(f"{flag}: no config.json (not a `sern grasp learn` run directory)")
    doc = validate.read_json_object(path / "config.json", {"config": dict, "objects": list},
                                    what="run configuration", advice="rerun the part")
    cfg = doc["config"]
    for key in ("policies", "num_seeds", "rounds", "explore"):
        if key not in cfg:
            raise ValueError(f"{flag}: config.json has no config.{key}")
    if not (path / "results.npz").is_file():
        raise ValueError(f"{flag}: no results.npz: the run has not finished (rerun its "
                         "command to resume it)")
    try:
        res = io.load_npz(path / "results.npz", advice="rerun the part")
    except ValueError as exc:
        raise ValueError(f"{flag}: {exc}") from None
    shape = (int(cfg["rounds"]) + 1, len(doc["objects"]), len(cfg["policies"]),
             int(cfg["num_seeds"]))
    for name in RAW:
        if name not in res:
            raise ValueError(f"{flag}: results.npz has no {name}")
        if tuple(res[name].shape) != shape:
            raise ValueError(f"{flag}: {name} has shape {tuple(res[name].shape)}, not the "
                             f"{shape} of its config.json")
    lv, ex = np.asarray(res["lowvar_eval"], np.float64), np.asarray(res["explore_success"],
                                                                     np.float64)
    if not (np.isfinite(lv).all() and np.isfinite(ex[1:]).all()):
        raise ValueError(f"{flag}: rounds without results (NaN): the run has not finished, "
                         "or ran without the fixed-pose evaluation (--eval-poses 0)")
    return {"path": path, "config": cfg, "objects": [str(o) for o in doc["objects"]],
            "theta0": doc.get("theta0"), "fingerprint": doc.get("fingerprint"),
            "benchmark": _named_benchmark(doc, path), "lowvar_eval": lv,
            "explore_success": ex}


def _named_benchmark(doc: dict, path: Path) -> dict | None:
    """The benchmark a run directory says it ran (config.json or metadata.json), if any."""
    from sern_jax.infra import io

    found = []
    meta = {}
    if (path / "metadata.json").is_file():
        try:
            meta = io.load_json(path / "metadata.json")
        except (OSError, ValueError):
            meta = {}
    for holder in (doc, doc.get("config", {}), meta if isinstance(meta, dict) else {}):
        b = holder.get("benchmark") if isinstance(holder, dict) else None
        if isinstance(b, dict) and "name" in b and "version" in b:
            found.append({"name": str(b["name"]), "version": b["version"]})
    return found[0] if found else None


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies below it (records name
    files the same way on every machine), else as given."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _benchmark_file(text: str) -> tuple[dict, Path]:
    """--benchmark NAME (a shipped benchmark) or a path to a benchmark JSON file."""
    from sern_jax.infra import validate
    import sern_jax

    if text.endswith(".json"):
        path = Path(text)
    else:
        shipped = Path(sern_jax.__file__).parent / "grasp" / "data" / "benchmarks"
        path = shipped / f"{text}.json"
        if not path.is_file():
            known = sorted(p.stem for p in shipped.glob("*.json")) if shipped.is_dir() else []
            raise ValueError(f"--benchmark: unknown benchmark {text!r}; known: "
                             f"{', '.join(known) or 'none'}")
    if not path.is_file():
        raise ValueError(f"--benchmark {text}: no such file")
    try:
        doc = validate.read_json_object(path, {"name": str, "version": (int, str)},
                                        what="benchmark file")
    except ValueError as exc:
        raise ValueError(f"--benchmark: {exc}") from None
    return doc, path


def _screen_rows(files, objects) -> list[dict]:
    from sern_jax.infra import validate

    rows, rules = {}, {}
    for f in files:
        try:
            doc = validate.read_json_object(f, {"objects": list}, what="screen",
                                            advice="give the JSON of `sern grasp screen "
                                                   "--json-out`")
        except ValueError as exc:
            raise ValueError(f"--screen: {exc}") from None
        rule = doc.get("rule", {}) if isinstance(doc.get("rule"), dict) else {}
        for row in doc["objects"]:
            if not isinstance(row, dict) or "object" not in row:
                raise ValueError(f"--screen {f}: a row without 'object'")
            name = str(row["object"])
            if name not in objects:
                continue
            for key in ("greedy_success", "best_success_fresh", "poses", "trials",
                        "fresh_trials"):
                if not isinstance(row.get(key), (int, float)) or isinstance(row.get(key),
                                                                            bool):
                    raise ValueError(f"--screen {f}: the row of {name} has no number "
                                     f"{key!r} (a screen on fresh trials gives it)")
            if name in rows and rows[name] != row:
                raise ValueError(f"--screen: two different rows for {name}")
            rows[name], rules[name] = row, rule
    missing = [o for o in objects if o not in rows]
    if missing:
        raise ValueError(f"--screen: no row for {', '.join(missing)}")
    out = []
    for o in objects:
        row, rule = rows[o], rules[o]
        entry = {"object": o, "theta0_greedy": 100.0 * float(row["greedy_success"]),
                 "best_fresh": 100.0 * float(row["best_success_fresh"]),
                 "poses": int(row["poses"]), "trials": int(row["trials"]),
                 "fresh_trials": int(row["fresh_trials"])}
        if "max_greedy_success" in rule and "min_best_success" in rule:
            entry["passed"] = bool(row["greedy_success"] <= rule["max_greedy_success"]
                                   and row["best_success_fresh"] >= rule["min_best_success"])
        else:
            entry["passed"] = None
        out.append(entry)
    return out


def collect(runs, screens, benchmark: str | None = None,
            reference: str = "sern") -> tuple[dict, dict]:
    """The benchmark's grid from its parts: (meta, per_seed), nothing written.

    Args:
      runs: the parts' run directories.
      screens: screen JSON files (rows of every object are needed).
      benchmark: a shipped benchmark's name or a benchmark JSON file; None: the name the
        run directories record.
      reference: learner ``a`` of every comparison.

    Returns:
      meta (JSON-ready) and object -> {"learners", "lowvar_eval" [R + 1, Q, S],
      "explore_success" [R + 1, Q, S]}.

    Raises:
      ValueError: one line naming the flag (``--runs``, ``--screen``, ``--benchmark``,
      ``--reference``).
    """
    if not runs:
        raise ValueError("--runs: no run directories given")
    parts = [_read_part(Path(r)) for r in runs]
    first = parts[0]
    for p in parts[1:]:
        for key in PROTOCOL:
            if first["config"].get(key) != p["config"].get(key):
                raise ValueError(f"--runs {p['path']}: {key} = {p['config'].get(key)!r}, but "
                                 f"{first['path']} has {first['config'].get(key)!r} (the "
                                 "parts of one benchmark share its protocol)")
        if p["theta0"] != first["theta0"]:
            raise ValueError(f"--runs {p['path']}: θ0 {p['theta0']} differs from "
                             f"{first['path']}'s {first['theta0']}")
    cells, objects, learners = {}, [], []
    for p in parts:
        for o, name in enumerate(p["objects"]):
            if "/" in name or name.startswith("."):
                raise ValueError(f"--runs {p['path']}: object name {name!r} cannot name a file")
            if name not in objects:
                objects.append(name)
            for q, learner in enumerate(p["config"]["policies"]):
                if learner not in learners:
                    learners.append(learner)
                if (name, learner) in cells:
                    raise ValueError(f"--runs {p['path']}: {name} × {learner} is also in "
                                     f"{cells[name, learner][0]}")
                cells[name, learner] = (p["path"], p["lowvar_eval"][:, o, q],
                                        p["explore_success"][:, o, q])
    missing = [f"{o} × {q}" for o in objects for q in learners if (o, q) not in cells]
    if missing:
        raise ValueError(f"--runs: no part ran {', '.join(missing[:5])}"
                         + (f" (and {len(missing) - 5} more)" if len(missing) > 5 else ""))
    if reference not in learners:
        raise ValueError(f"--reference: {reference!r} is not among the parts' learners "
                         f"({', '.join(learners)})")
    if len(learners) < 2:
        raise ValueError("--runs: comparisons need at least two learners")
    if len(objects) < 2:
        raise ValueError("--runs: objects as a random factor need at least two objects")
    named = {json.dumps(p["benchmark"], sort_keys=True) for p in parts}
    recorded = None if named == {"null"} else named
    if recorded is not None and len(recorded) > 1:
        raise ValueError(f"--runs: the parts name different benchmarks: {sorted(recorded)}")
    bench_doc, bench_path, objects_missing = None, None, None
    if benchmark is not None:
        bench_doc, bench_path = _benchmark_file(benchmark)
        info = {"name": str(bench_doc["name"]), "version": bench_doc["version"]}
        if recorded is not None and json.loads(next(iter(recorded))) not in (None, info):
            raise ValueError(f"--benchmark: the parts ran {next(iter(recorded))}, not {info}")
        declared = bench_doc.get("metrics")
        if isinstance(declared, dict):
            bs = _bs()
            for family, ours in (("primary", bs.PRIMARY), ("secondary", bs.SECONDARY)):
                if family in declared and list(declared[family]) != list(ours):
                    raise ValueError(f"--benchmark {benchmark}: {family} metrics "
                                     f"{declared[family]}, but this summary computes "
                                     f"{list(ours)}")
        listed = [str(o["name"]) if isinstance(o, dict) else str(o)
                  for o in bench_doc.get("objects", []) if isinstance(o, (dict, str))]
        if listed:
            extra = [o for o in objects if o not in listed]
            if extra:
                raise ValueError(f"--runs: {', '.join(extra)} is not among the objects of "
                                 f"benchmark {info['name']}")
            objects_missing = [o for o in listed if o not in objects]
            objects = [o for o in listed if o in objects]  # the benchmark's order
    else:
        if recorded is None or json.loads(next(iter(recorded))) is None:
            raise ValueError("--benchmark: the run directories do not name their benchmark; "
                             "give --benchmark NAME")
        info = json.loads(next(iter(recorded)))
    screen = _screen_rows(screens or [], objects)
    cfg = first["config"]
    per_seed = {}
    for o in objects:
        per_seed[o] = {"learners": list(learners),
                       "lowvar_eval": np.stack([cells[o, q][1] for q in learners], 1),
                       "explore_success": np.stack([cells[o, q][2] for q in learners], 1)}
    meta = {"benchmark": {"name": info["name"], "version": info["version"]},
            "benchmark_file": None if bench_path is None else _shown(bench_path),
            "objects": objects, "objects_missing": objects_missing,
            "learners": learners, "reference": reference,
            "seeds": int(cfg["num_seeds"]), "rounds": int(cfg["rounds"]),
            "explore": int(cfg["explore"]),
            "protocol": {k: cfg.get(k) for k in PROTOCOL},
            "theta0": first["theta0"],
            "parts": [{"run": str(p["path"]), "fingerprint": p["fingerprint"],
                       "objects": p["objects"], "learners": list(p["config"]["policies"]),
                       "backend": p["config"].get("backend"),
                       "hyperparameters": {k: p["config"].get(k) for k in
                                           ("alpha", "epsilon", "alpha0", "p", "hyper")}}
                      for p in parts],
            "screen_files": [str(s) for s in screens or []],
            "screen": screen}
    return meta, per_seed


# ----------------------------------------------------------------------------- the record


def _metrics(arrays: dict, explore: int) -> dict:
    return _bs().run_metrics(arrays["lowvar_eval"], arrays["explore_success"], explore)


def summarise_record(meta: dict, per_seed: dict) -> dict:
    """summary.json's content from ``meta`` and the per-seed arrays alone."""
    bs = _bs()
    objects, learners = meta["objects"], meta["learners"]
    per_metric = {m: [] for m in bs.METRICS}
    for o in objects:
        if list(per_seed[o]["learners"]) != list(learners):
            raise ValueError(f"per_seed/{o}: learners {list(per_seed[o]['learners'])} are not "
                             f"the record's {learners}")
        for m, v in _metrics(per_seed[o], meta["explore"]).items():
            per_metric[m].append(v)
    metrics = {m: np.stack(v) for m, v in per_metric.items()}  # [O, Q, S]
    comparisons, rows = bs.compare(metrics, learners, objects, meta["reference"])
    lowvar = np.stack([per_seed[o]["lowvar_eval"] for o in objects], 1)  # [R + 1, O, Q, S]
    return {
        "benchmark": meta["benchmark"],
        "objects": objects,
        "objects_missing": meta.get("objects_missing"),
        "seeds": meta["seeds"],
        "rounds": meta["rounds"],
        "explore": meta["explore"],
        "learners": learners,
        "reference": meta["reference"],
        "theta0": meta["theta0"],
        "screen": meta["screen"],
        "metrics": {"primary": list(bs.PRIMARY), "secondary": list(bs.SECONDARY),
                    "units": bs.UNITS, "tost_margin": bs.TOST_MARGIN, "level": bs.LEVEL},
        "units": "percentage points",
        "conventions": CONVENTIONS,
        "comparisons": comparisons,
        "per_object": rows,
        "learner_means": bs.learner_means(metrics, learners),
        "curves": bs.curves(lowvar, learners),
        "per_seed_files": [f"per_seed/{o}.npz" for o in objects],
    }


def write_record(out, meta: dict, per_seed: dict, summary: dict) -> None:
    """per_seed/<object>.npz, meta.json and summary.json under ``out``."""
    from sern_jax.infra import io

    out = Path(out)
    (out / "per_seed").mkdir(parents=True, exist_ok=True)
    for o, arrays in per_seed.items():
        metrics = _metrics(arrays, meta["explore"])
        io.save_npz(out / "per_seed" / f"{o}.npz", learners=np.asarray(arrays["learners"]),
                    lowvar_eval=arrays["lowvar_eval"],
                    explore_success=arrays["explore_success"],
                    **{f"metric_{m}": v for m, v in metrics.items()})
    io.save_json(out / "meta.json", meta)
    io.save_json(out / "summary.json", summary)


def load_record(out) -> tuple[dict, dict]:
    """(meta, per_seed) from a record written by :func:`write_record`; a per-seed file whose
    stored metrics differ from its raw arrays is refused (``ValueError``)."""
    from sern_jax.infra import io, validate

    out = Path(out)
    if not (out / "meta.json").is_file():
        raise ValueError(f"--out {out}: no meta.json (give --runs and --screen to make the "
                         "record)")
    meta = validate.read_json_object(out / "meta.json", {
        "benchmark": dict, "objects": list, "learners": list, "reference": str, "seeds": int,
        "rounds": int, "explore": int, "screen": list}, what="benchmark record")
    per_seed = {}
    for o in meta["objects"]:
        path = out / "per_seed" / f"{o}.npz"
        if not path.is_file():
            raise ValueError(f"--out {out}: no per_seed/{o}.npz")
        a = io.load_npz(path, advice="restore it from git")
        arrays = {"learners": [str(v) for v in a["learners"]],
                  "lowvar_eval": a["lowvar_eval"], "explore_success": a["explore_success"]}
        for m, v in _metrics(arrays, meta["explore"]).items():
            if not np.array_equal(a[f"metric_{m}"], v):
                raise ValueError(f"{path}: metric_{m} is not what its raw arrays give")
        per_seed[o] = arrays
    return meta, per_seed


def summarise(out, runs=None, screens=None, benchmark: str | None = None,
              reference: str = "sern", write: bool = True) -> dict:
    """The summary of the record under ``out``; with ``runs``, made from the parts first
    (everything is read and checked before anything is written)."""
    if runs:
        meta, per_seed = collect(runs, screens, benchmark, reference)
        # the written record is what the summary is computed from (per-seed files round-trip
        # bit for bit: float64 arrays)
        summary = summarise_record(meta, per_seed)
        if write:
            write_record(out, meta, per_seed, summary)
        return summary
    meta, per_seed = load_record(out)
    summary = summarise_record(meta, per_seed)
    if write:
        from sern_jax.infra import io

        io.save_json(Path(out) / "summary.json", summary)
    return summary


# ----------------------------------------------------------------------------- power


def power_table(sd_seeds, sd_objects, objects, seeds, alpha: float = 0.05, family: int = 4,
                power: float = 0.8) -> list[dict]:
    """Detectable differences (points) at ``power`` over a grid of designs, at Holm's
    strictest level alpha / family."""
    bs = _bs()
    rows = []
    for o in objects:
        for s in seeds:
            for sd_o in sd_objects:
                for sd_s in sd_seeds:
                    d = bs.detectable_difference(sd_s, sd_o, o, s, alpha, family, power)
                    rows.append({"objects": o, "seeds": s, "sd_object": sd_o, "sd_seed": sd_s,
                                 "alpha": d.alpha, "power": d.power, "se": d.se, "df": d.df,
                                 "detectable": d.diff, "method": d.method})
    return rows


# ----------------------------------------------------------------------------- command line


def main(argv=None) -> int:
    from sern_jax.infra import validate

    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p_sum = sub.add_parser("summarise", help="per-seed files and summary.json from the parts")
    p_sum.add_argument("--runs", nargs="+", default=None, metavar="RUN_DIR",
                       help="the parts' `sern grasp learn` run directories (default: "
                            "recompute from the record under --out)")
    p_sum.add_argument("--screen", nargs="+", default=None, metavar="FILE",
                       help="`sern grasp screen --json-out` files with every object's row")
    p_sum.add_argument("--benchmark", default=None, metavar="NAME",
                       help="a shipped benchmark's name or a benchmark JSON file (default: "
                            "the name the run directories record)")
    p_sum.add_argument("--reference", default="sern",
                       help="learner a of every comparison a − b")
    p_sum.add_argument("--out", default="experiments/results/benchmark")
    p_pow = sub.add_parser("power", help="detectable differences for the pre-registration")
    p_pow.add_argument("--sd-seed", default="2,3.5",
                       help="comma list: SDs over seeds of the paired differences (points)")
    p_pow.add_argument("--sd-object", default="0,1",
                       help="comma list: SDs between objects of the true differences")
    p_pow.add_argument("--objects", default="12", help="comma list of object counts")
    p_pow.add_argument("--seeds", default="40", help="comma list of seed counts")
    p_pow.add_argument("--alpha", type=validate.float_in(0.0, 1.0, low_open=True,
                                                         high_open=True), default=0.05)
    p_pow.add_argument("--family", type=validate.int_in(1, 10_000), default=4,
                       help="comparisons Holm corrects over (alpha / family at its first step)")
    p_pow.add_argument("--power", type=validate.float_in(0.0, 1.0, low_open=True,
                                                         high_open=True), default=0.8)
    p_pow.add_argument("--json-out", default=None)
    p_re = sub.add_parser("rerun-check", help="compare a rerun of one cell with its part, "
                                              "bit for bit")
    p_re.add_argument("--part", required=True, help="the committed part's run directory")
    p_re.add_argument("--rerun", nargs="+", required=True, metavar="RUN_DIR",
                      help="run directories of the same object with some of its learners")
    p_re.add_argument("--json-out", default=None)
    args = parser.parse_args(argv)
    try:
        if args.what == "power":
            return _power(args)
        if args.what == "rerun-check":
            validate.out_file(args.json_out, "--json-out")
            report = rerun_check(Path(args.part), [Path(r) for r in args.rerun])
            print(json.dumps(report, indent=1))
            if args.json_out:
                from sern_jax.infra import io

                io.save_json(args.json_out, report)
            return 0
        validate.out_dir(args.out, "--out")
        if args.runs is None:
            for flag, value in (("--screen", args.screen), ("--benchmark", args.benchmark)):
                if value is not None:
                    raise ValueError(f"{flag} is read only with --runs; leave it out")
        elif not args.screen:
            raise ValueError("--screen: give the screen of the benchmark's objects "
                             "(`sern grasp screen --json-out FILE`)")
        with validate.quiet_numerics():
            s = summarise(args.out, args.runs, args.screen, args.benchmark, args.reference)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog} {args.what}: error: {' '.join(str(exc).split())}",
              file=sys.stderr)
        return 2
    _print_summary(s)
    print(f"wrote {Path(args.out) / 'summary.json'}")
    return 0


_RESULT_FIELDS = ("lowvar_eval", "paper_eval", "explore_success", "explore_action",
                  "pseudo_regret")


def rerun_check(part: Path, reruns: list[Path]) -> dict:
    """Each rerun's arrays against the part's, learner by learner: the cells that differ
    (NaN placeholders compared as equal) and the run seconds of each."""
    ref = _read_part(part)
    ref_arrays = np.load(part / "results.npz")
    report = {"part": str(part), "reruns": []}
    for rerun in reruns:
        other = _read_part(rerun)
        if other["objects"] != ref["objects"]:
            raise ValueError(f"--rerun {rerun}: objects {other['objects']} are not the part's "
                             f"{ref['objects']}")
        arrays = np.load(rerun / "results.npz")
        meta = json.loads((rerun / "metadata.json").read_text())
        rows = {}
        for q, name in enumerate(other["config"]["policies"]):
            qr = list(ref["config"]["policies"]).index(name)
            diff = {}
            for f in _RESULT_FIELDS:
                a, b = ref_arrays[f][:, :, qr], arrays[f][:, :, q]
                same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else a == b
                diff[f] = {"cells": int(same.size), "differ": int((~same).sum())}
            rows[name] = diff
        report["reruns"].append({"run": str(rerun), "seconds": meta.get("seconds"),
                                 "env": meta.get("env"), "learners": rows,
                                 "identical": all(d["differ"] == 0 for r in rows.values()
                                                  for d in r.values())})
    return report


def _power(args) -> int:
    from sern_jax.infra import io, validate

    def positive(text):
        v = float(text)
        if not v >= 0 or v == float("inf"):
            raise ValueError(text)
        return v

    sd_s = validate.comma_list_of(args.sd_seed, "--sd-seed", positive, "numbers >= 0")
    sd_o = validate.comma_list_of(args.sd_object, "--sd-object", positive, "numbers >= 0")

    def count(low):
        def parse(text):
            v = int(text)
            if not low <= v <= 100_000:
                raise ValueError(text)
            return v
        return parse

    objects = validate.comma_list_of(args.objects, "--objects", count(1),
                                     "integers in [1, 100000]")
    seeds = validate.comma_list_of(args.seeds, "--seeds", count(2), "integers in [2, 100000]")
    validate.out_file(args.json_out, "--json-out")
    rows = power_table(sd_s, sd_o, objects, seeds, args.alpha, args.family, args.power)
    print(f"detectable difference (points) at {args.power:.0%} power, two-sided t test at "
          f"alpha {args.alpha} / {args.family} (Holm's first step), noncentral t; objects as "
          "a random factor (one object: the test over seeds)")
    print(f"{'objects':>7} {'seeds':>5} {'sd_object':>9} {'sd_seed':>7} {'se':>6} "
          f"{'detectable':>10}")
    for r in rows:
        print(f"{r['objects']:7d} {r['seeds']:5d} {r['sd_object']:9.2f} {r['sd_seed']:7.2f} "
              f"{r['se']:6.3f} {r['detectable']:10.2f}")
    if args.json_out:
        io.save_json(args.json_out, {"rows": rows})
    return 0


def _print_summary(s: dict) -> None:
    print(f"{s['benchmark']['name']} v{s['benchmark']['version']}: {len(s['objects'])} "
          f"objects × {len(s['learners'])} learners × {s['seeds']} seeds")
    for c in s["comparisons"]:
        tost = c["tost"]
        eq = "" if tost["p"] is None else (f"  TOST ±{tost['margin']:g}: p {tost['p']:.3g}"
                                           + (" equivalent" if tost["equivalent"] else ""))
        print(f"  {c['a']} − {c['b']:<14s} {c['metric']:<16s} {c['diff']:+7.2f} "
              f"[{c['ci_low']:+.2f}, {c['ci_high']:+.2f}]  p {c['p']:.3g}  Holm p "
              f"{c['holm_p']:.3g} ({c['family']}){eq}")
    failed = [e["object"] for e in s["screen"] if e["passed"] is False]
    if failed:
        print(f"note: {', '.join(failed)} did not pass the screen's rule")
    print("(objects as a random factor: 95 % Student t over the object means; Holm within "
          "the primary and within the secondary family)")


if __name__ == "__main__":
    raise SystemExit(main())
