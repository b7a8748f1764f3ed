"""``sern grasp dataset | pretrain | screen | learn``: arguments only; work happens in
:mod:`dataset`, :mod:`pretrain`, :mod:`driver` and, for ``learn --benchmark``,
:mod:`sern_jax.grasp.online.benchmark` (imported inside each command, so
``sern --help`` stays fast: only the learners' registry and its jax/optax imports are
loaded up front, so that every registered learner's hyperparameters are flags). Figures are
handed in by :mod:`sern_jax.commands.main`."""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import time
from collections.abc import Callable
from pathlib import Path

from sern_jax.infra import validate

__all__ = [
    "add_dataset_parser",
    "add_learn_parser",
    "add_pretrain_parser",
    "add_screen_parser",
    "format_table",
    "run_learn",
]

_FMT = argparse.ArgumentDefaultsHelpFormatter


_positive_int = validate.int_at_least(1)  # argparse type: an integer >= 1


class _Given(argparse.Action):
    """argparse's ``store`` that also notes the flag as typed (``args.given``: dest ->
    flag), so a flag the user gave is told from its default (``--benchmark`` refuses the
    flags it fixes even when typed with their default value)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        given = dict(getattr(namespace, "given", None) or {})
        given[self.dest] = option_string or self.option_strings[0]
        namespace.given = given


def _check_out(path: str | None, what: str = "--out") -> None:
    """Refuses an output path that cannot become a writable directory, before any work;
    leaves nothing behind (:func:`validate.out_dir`)."""
    validate.out_dir(path, what)


def _check_file_out(path: str | None, what: str = "--json-out") -> None:
    """Refuses an output file that could not be written, before any work
    (:func:`validate.out_file`: a temporary file is tried where it would go)."""
    validate.out_file(path, what)


def _check_seed(seed: int) -> None:
    if not 0 <= seed < 2**31:
        raise ValueError(f"--seed must be in [0, 2**31), got {seed}")


def _check_size(est, out) -> None:
    """Refuses a run whose estimate (:mod:`sern_jax.grasp.online.budget`) cannot fit this machine;
    prints the estimate when the run is long."""
    from sern_jax.grasp.online import budget

    budget.check(est, out=out)
    if est.seconds > 600:
        print(f"estimated: {est.trials:,} trials, {est.contexts:,} poses, about "
              f"{budget.fmt_time(est.seconds)} on this machine, "
              f"{budget.fmt_bytes(est.memory_bytes)} of memory", flush=True)


# ----------------------------------------------------------------------------- dataset


def add_dataset_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "dataset", formatter_class=_FMT,
        help="simulate the pretraining data D0 (labelled grasps of many objects)",
        description=(
            "Simulates the 64 antipodal candidates of --poses resting poses of --objects "
            "procedural training objects, one randomised trial per valid candidate (the label "
            "a robot would see: 1 success, 0 failure), and stores depth images, candidates and "
            "labels in npz shards. Deterministic given --seed; an interrupted run resumes from "
            "the finished shards. The defaults give 204,800 candidate slots (~200k labelled "
            "grasps)."))
    p.add_argument("--objects", type=_positive_int, default=200, help="training objects")
    p.add_argument("--poses", type=_positive_int, default=16, help="resting poses per object")
    p.add_argument("--trials", type=_positive_int, default=1,
                   help="trials per grasp (1 = one Bernoulli label; more = frequencies)")
    p.add_argument("--backend", choices=("native", "mjx"), default="native")
    p.add_argument("--objects-per-shard", type=validate.int_in(1, 100_000), default=None,
                   metavar="N",
                   help="objects per shard file, the unit of resume and of --ray tasks "
                        "(default 10; 1 keeps many Ray workers evenly busy: docs/CLUSTER.md); "
                        "the shards of one object hold the same arrays whatever N")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/d0", help="dataset directory")
    p.add_argument("--no-progress", action="store_true")
    from sern_jax.infra import distributed  # --ray [ADDRESS]: shards as Ray tasks

    distributed.add_arguments(p)
    p.set_defaults(func=_run_dataset)
    return p


def _run_dataset(args) -> int:
    from sern_jax.infra import distributed

    _check_seed(args.seed)
    _check_out(args.out)
    ray = distributed.from_args(args)  # None without --ray
    distributed.check_backend(args.backend, ray)  # mjx tasks on a GPU only
    from sern_jax.grasp.online import budget
    from sern_jax.grasp.model import dataset

    try:
        shard = getattr(args, "objects_per_shard", None)
        config = dataset.DatasetConfig(seed=args.seed, num_objects=args.objects,
                                       poses_per_object=args.poses,
                                       trials_per_grasp=args.trials, backend=args.backend,
                                       **({} if shard is None else
                                          {"objects_per_shard": shard}))
    except ValueError as e:
        raise ValueError(_dataset_flags(str(e))) from None
    _check_size(budget.dataset(objects=args.objects, poses=args.poses, trials=args.trials,
                               objects_per_shard=config.objects_per_shard), args.out)
    summary = dataset.generate(config, args.out, progress=not args.no_progress,
                               **({"ray": ray} if ray is not None else {}))
    print(json.dumps(summary, indent=2))
    print(f"dataset directory: {args.out}")
    return 0


_DATASET_FLAGS = {"num_objects": "--objects", "poses_per_object": "--poses",
                  "trials_per_grasp": "--trials", "seed": "--seed", "backend": "--backend",
                  "objects_per_shard": "--objects-per-shard"}


def _dataset_flags(message: str) -> str:
    message = re.sub(r"\b(" + "|".join(_DATASET_FLAGS) + r")\b",
                     lambda m: _DATASET_FLAGS[m.group(1)], message)
    return re.sub(r"^(\d+) objects x (\d+) poses", r"--objects \1 x --poses \2", message)


# ----------------------------------------------------------------------------- pretrain


def add_pretrain_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "pretrain", formatter_class=_FMT,
        help="train θ0 on D0, evaluate on held-out objects, pick the DPP core set",
        description=(
            "Trains the quality network on a D0 made by `sern grasp dataset` (Adam, BCE; a "
            "checkpoint per epoch, so an interrupted run resumes), reports ROC-AUC, accuracy "
            "and calibration (ECE, reliability diagram) on procedural objects never seen in "
            "training against success frequencies from --heldout-trials trials, picks the core "
            "set C (k-DPP on the network's features) and a random core set of the same size, "
            "and screens the named objects with the hard-set rule. --install copies θ0, the "
            "core sets, the screen and the manifest into the package (sern_jax/grasp/data)."))
    p.add_argument("--data", default="runs/d0", help="dataset directory")
    p.add_argument("--out", default="runs/theta0", help="output directory")
    p.add_argument("--epochs", type=_positive_int, default=8)
    p.add_argument("--batch-size", type=_positive_int, default=128)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--loss", choices=("bce", "l1"), default="bce")
    p.add_argument("--heldout-objects", type=_positive_int, default=12)
    p.add_argument("--heldout-poses", type=_positive_int, default=4)
    p.add_argument("--heldout-trials", type=_positive_int, default=16)
    p.add_argument("--core-k", type=_positive_int, default=172)
    p.add_argument("--screen-poses", type=_positive_int, default=8)
    p.add_argument("--screen-trials", type=_positive_int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--install", action="store_true",
                   help="copy the result into the package data (what `sern grasp learn` uses)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run_pretrain)
    return p


def _run_pretrain(args) -> int:
    _check_out(args.out)
    _check_seed(args.seed)
    validate.finite_float(args.lr, "--lr", low=0, low_open=True, float32_normal=True)
    if not Path(args.data, "config.json").exists():
        raise ValueError(f"--data {args.data} is not a dataset directory; make one with "
                         "`sern grasp dataset --out DIR`")
    if args.install:
        _check_out(str(_data_dir()), "--install")
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts, dataset, pretrain
    from sern_jax.grasp.online import budget
    from sern_jax.grasp.world import objects

    try:
        config = pretrain.PretrainConfig(
            epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr,
            loss=args.loss, seed=args.seed, heldout_objects=args.heldout_objects,
            heldout_poses=args.heldout_poses, heldout_trials=args.heldout_trials,
            core_k=args.core_k)
    except ValueError as e:
        raise ValueError(_pretrain_flags(str(e))) from None
    # D0's size from its config.json (and summary.json when finished), before loading it
    try:
        data_config, _ = dataset.read_config(Path(args.data, "config.json"))
    except ValueError as exc:
        raise ValueError(f"--data {args.data}: {exc}") from None
    grasps = data_config.max_grasps
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        grasps = int(io.load_json(Path(args.data, "summary.json"))["labelled_grasps"])
    _check_size(budget.pretrain(
        grasps=grasps, contexts=data_config.num_objects * data_config.poses_per_object,
        epochs=args.epochs, batch_size=args.batch_size, heldout_objects=args.heldout_objects,
        heldout_poses=args.heldout_poses, heldout_trials=args.heldout_trials,
        core_k=args.core_k, screen_objects=len(objects.object_names()),
        screen_poses=args.screen_poses, screen_trials=args.screen_trials), args.out)
    manifest = pretrain.pretrain(args.data, config, args.out, progress=not args.no_progress)
    theta0 = artifacts.load_theta0(args.out, flag="--out")
    specs = [objects.make_object(n) for n in objects.object_names()]
    rows = pretrain.screen(theta0.network, theta0.params, specs, args.screen_poses,
                           args.screen_trials, progress=not args.no_progress)
    artifacts.save_screen(args.out, {"rule": pretrain.HARD_RULE, "objects": rows})
    _print_screen(rows)
    print(json.dumps(manifest["heldout"] | {"objects": None}, indent=2))
    if args.install:
        artifacts.install(args.out)
        print(f"installed into {artifacts.DATA_DIR}")
    return 0


_PRETRAIN_FLAGS = {"epochs": "--epochs", "batch_size": "--batch-size",
                   "learning_rate": "--lr", "heldout_objects": "--heldout-objects",
                   "heldout_poses": "--heldout-poses", "heldout_trials": "--heldout-trials",
                   "core_k": "--core-k", "loss": "--loss", "seed": "--seed"}


def _pretrain_flags(message: str) -> str:
    return re.sub(r"\b(" + "|".join(_PRETRAIN_FLAGS) + r")\b",
                  lambda m: _PRETRAIN_FLAGS[m.group(1)], message)


def _data_dir() -> Path:
    from sern_jax.grasp.model import artifacts

    return Path(artifacts.DATA_DIR)


def _print_screen(rows) -> None:
    print(f"{'object':>20s}  θ0 greedy  best  mean  hard")
    for r in rows:
        print(f"{r['object']:>20s}  {r['greedy_success']:9.2f}  {r['best_success']:4.2f}  "
              f"{r['mean_success']:4.2f}  {'yes' if r['hard'] else ''}")


# ----------------------------------------------------------------------------- screen


def add_screen_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "screen", formatter_class=_FMT,
        help="the hard-set rule: θ0's greedy success vs the best candidate's, per object",
        description=(
            "For each object: over --poses random resting poses, the success frequency "
            "(--trials trials) of θ0's greedy choice and of the best of the 64 candidates. An "
            "object is hard when θ0's greedy choice succeeds at most 60% of the time while "
            "the best candidate succeeds at least 80% of the time."))
    p.add_argument("objects", nargs="*", metavar="OBJECT",
                   help="object names (default: every named object)")
    p.add_argument("--mesh", action="append", default=[], metavar="PATH")
    p.add_argument("--mesh-units", choices=_MESH_UNITS, default="auto",
                   help="units of the mesh files' coordinates (as in `sern grasp show`)")
    p.add_argument("--poses", type=_positive_int, default=8)
    p.add_argument("--trials", type=_positive_int, default=8)
    p.add_argument("--theta0", default=None, help="θ0 directory (default: the shipped one)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json-out", default=None)
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run_screen)
    return p


_MESH_UNITS = ("auto", "m", "cm", "mm")


def _specs(names, meshes, default_names, units="auto"):
    from sern_jax.grasp.world import objects

    names = list(names) or ([] if meshes else list(default_names))
    specs = [objects.resolve_object(n, units=units) for n in names]
    for m in meshes:
        try:
            specs.append(objects.load_mesh(m, units=units))
        except (ValueError, OSError) as exc:
            text = str(exc) if isinstance(exc, ValueError) else (exc.strerror or str(exc))
            raise ValueError(text if "--mesh" in text else f"--mesh {m}: {text}") from None
    if not specs:
        raise ValueError("no objects given")
    seen = set()
    for s in specs:
        if s.name in seen:
            raise ValueError(f"object {s.name!r} given twice")
        seen.add(s.name)
    return specs


def _run_screen(args) -> int:
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts, pretrain
    from sern_jax.grasp.online import budget
    from sern_jax.grasp.world import objects

    _check_seed(args.seed)
    _check_file_out(args.json_out)
    specs = _specs(args.objects, args.mesh, objects.object_names(),
                   getattr(args, "mesh_units", "auto"))
    _check_size(budget.screen(objects=len(specs), poses=args.poses, trials=args.trials), None)
    theta0 = artifacts.load_theta0(args.theta0)
    rows = pretrain.screen(theta0.network, theta0.params, specs, args.poses, args.trials,
                           seed=args.seed, progress=not args.no_progress)
    _print_screen(rows)
    if args.json_out:
        io.save_json(args.json_out, {"rule": pretrain.HARD_RULE, "objects": rows})
    return 0


# ----------------------------------------------------------------------------- learn


def add_learn_parser(subparsers, make_figures: Callable | None = None) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "learn", formatter_class=_FMT,
        help="online SERN grasp learning (Algorithm 1) and the paper's Table I",
        description=(
            "Fine-tunes the shipped θ0 online on each object with each policy and seed: rounds "
            "of --explore grasps (each on a fresh resting pose, chosen by the policy over the "
            "valid candidates), an optax update on the collected data plus the core set, and "
            "--evaluate greedy grasps (the paper's evaluation) plus a fixed-pose evaluation "
            "(--eval-poses fixed poses x --eval-trials trials). Writes table.md / table.json in "
            "the paper's Table I format, results.npz, figures and a checkpoint per round (an "
            "interrupted run resumes). Default objects: the hard set chosen by the screen "
            "shipped with θ0. --benchmark NAME runs a versioned grasp-exploration benchmark "
            "(sern_jax/grasp/data/benchmarks): its objects, world, protocol, seeds and tuned "
            "hyperparameters, for the learners of --policies (default: the benchmark's; any "
            "other registered learner runs with its defaults); OBJECT names one of its "
            "objects (a part of the run), --seeds and --rounds a smaller run. Learners "
            "(--policies): " + _learner_summaries()))
    p.add_argument("objects", nargs="*", metavar="OBJECT",
                   help="object names or .obj/.stl paths (default: the hard set; with "
                        "--benchmark: objects of the benchmark, default all of them)")
    p.add_argument("--benchmark", default=None, metavar="NAME",
                   help="a shipped benchmark's name, or the path of a benchmark .json file: "
                        "objects, world, protocol, seeds and tuned hyperparameters come "
                        "from it (the flags it fixes are refused)")
    p.add_argument("--mesh", action="append", default=[], metavar="PATH",
                   help="an OBJ/STL mesh (repeatable); any mesh `sern grasp show` takes")
    p.add_argument("--mesh-units", choices=_MESH_UNITS, default="auto", action=_Given,
                   help="units of the mesh files' coordinates (as in `sern grasp show`)")
    p.add_argument("--policies", default="sern,egreedy,greedy", action=_Given,
                   help="comma-separated learners (sern_jax.learners.registry; with "
                        "--benchmark the default is the benchmark's learners)")
    p.add_argument("--seeds", type=_positive_int, default=5, action=_Given,
                   help="seeds per object and learner (with --benchmark: its first N "
                        "seeds, default all)")
    p.add_argument("--rounds", type=_positive_int, default=5, action=_Given,
                   help="rounds (with --benchmark: at most the benchmark's, default all)")
    p.add_argument("--explore", type=_positive_int, default=20, action=_Given)
    p.add_argument("--evaluate", type=_positive_int, default=5, action=_Given)
    _add_learner_flags(p)
    p.add_argument("--eval-poses", type=int, default=4, action=_Given,
                   help="fixed poses of the fixed-pose evaluation (0 = off)")
    p.add_argument("--eval-trials", type=int, default=8, action=_Given)
    p.add_argument("--regret-trials", type=int, default=0, metavar="M",
                   help="regret accounting: simulate every valid candidate of every "
                        "exploration pose M times (the oracle) and report each round's "
                        "pseudo-regret per policy; costly (64 x M trials per exploration "
                        "grasp, shared by the policies), 0 = off")
    p.add_argument("--regret-grasps", type=int, default=0, metavar="G",
                   help="with --regret-trials: run the oracle on the first G exploration "
                        "grasps of each round only and scale their pseudo-regret by "
                        "--explore / G (an unbiased estimate at G / --explore of the "
                        "cost); 0 = every grasp")
    p.add_argument("--fit-steps", type=validate.int_in(1, 100_000), default=40,
                   action=_Given)
    p.add_argument("--core-set", choices=("dpp", "random", "none"), default="dpp",
                   action=_Given)
    p.add_argument("--loss", choices=("bce", "l1"), default="bce", action=_Given)
    p.add_argument("--theta0", default=None, help="θ0 directory (default: the shipped one)")
    p.add_argument("--seed", type=int, default=0, action=_Given)
    p.add_argument("--backend", choices=("native", "mjx"), default="native", action=_Given,
                   help="physics of the trials: native MuJoCo on the CPU's cores, or MJX "
                        "(for a GPU: one compiled program for every object, then batches "
                        "of config.MJX_BATCH trials); outcomes of the two agree on most "
                        "trials but not bit for bit, so tables differ (with --benchmark: "
                        "default the benchmark's, and the run records the one used)")
    p.add_argument("--out", default=None, help="run directory (default runs/learn-<hash>)")
    p.add_argument("--json-out", default=None, help="write the Table I rows as JSON here")
    p.add_argument("--no-figures", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    from sern_jax.infra import distributed

    distributed.add_arguments(p)
    p.set_defaults(func=lambda args: run_learn(args, make_figures=make_figures))
    return p


def _pct(v) -> str:
    return "—" if v is None else f"{v:.0f}%"


def format_table(rows: list[dict]) -> str:
    """The paper's Table I layout: Round i mean (± population SD over seeds), Max, Imprv;
    a line under the table says which statistic the ± is."""
    num_r = len(rows[0]["rounds"])
    head = (["Obj.", "Alg.", "θ0"] + [f"Round {i + 1}" for i in range(num_r)]
            + ["Max.", "Imprv."])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["object"], r["policy"], _pct(r["theta0"])]
        cells += [f"{m:.0f}% (±{s:.2f})" for m, s in zip(r["rounds"], r["std"])]
        cells += [_pct(r["max"]), "—" if r["imprv"] is None else f"{100 * r['imprv']:.0f}%"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", ("(± = population standard deviation over the seeds, ddof 0: `std` in "
                   "table.json, which also has `sd` (ddof 1) and `se` = sd/√seeds, the "
                   "statistic the paper's Table I prints in parentheses.)")]
    if "lowvar_rounds" in rows[0]:
        lines += ["", ("Low-variance evaluation (greedy success probability on fixed "
                       "poses, mean over seeds; round 0 = θ0):"), ""]
        head = ["Obj.", "Alg."] + [f"R{i}" for i in range(num_r + 1)]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rows:
            cells = [r["object"], r["policy"]] + [
                f"{m:.0f}% (±{s:.1f})" for m, s in zip(r["lowvar_rounds"], r["lowvar_std"])]
            lines.append("| " + " | ".join(cells) + " |")
    if "pseudo_regret" in rows[0]:
        lines += ["", ("Pseudo-regret per round (expected successes lost to the best "
                       "candidate over the round's exploration grasps, oracle from "
                       "--regret-trials trials per candidate; mean ± std over seeds):"), ""]
        head = ["Obj.", "Alg."] + [f"Round {i + 1}" for i in range(num_r)] + ["Total"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rows:
            cells = [r["object"], r["policy"]] + [
                f"{m:.2f} (±{s:.2f})" for m, s in zip(r["pseudo_regret"],
                                                     r["pseudo_regret_std"])]
            cells.append(f"{sum(r['pseudo_regret']):.2f}")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


# OnlineConfig's field names -> the `sern grasp learn` flags that set them.
_LEARN_FLAGS = {
    "num_seeds": "--seeds", "rounds": "--rounds", "explore": "--explore",
    "evaluate": "--evaluate", "alpha0": "--alpha0", "alpha": "--alpha",
    "epsilon": "--epsilon", "eval_poses": "--eval-poses", "eval_trials": "--eval-trials",
    "regret_trials": "--regret-trials", "regret_grasps": "--regret-grasps",
    "fit_steps": "--fit-steps", "seed": "--seed",
    "core_set": "--core-set", "loss": "--loss", "backend": "--backend",
}


def _learner_summaries() -> str:
    from sern_jax.learners import registry

    return "; ".join(f"{name} ({spec.summary})" for name, spec in registry.LEARNERS.items())


def _flag_value(default):
    """argparse type of a hyperparameter with this default (bools as true/false)."""
    if isinstance(default, bool):
        def boolean(text: str) -> bool:
            if text.lower() in ("1", "true", "yes"):
                return True
            if text.lower() in ("0", "false", "no"):
                return False
            raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
        return boolean
    return type(default)


def _add_learner_flags(p) -> None:
    """Every registered learner's hyperparameters as flags: the fields of the registry's
    config dataclasses, with the flag, default and help their metadata give (a learner
    added to the registry brings its flags)."""
    from sern_jax.learners import registry

    for name, field in registry.hyperparameters().items():
        p.add_argument(field.metadata["flag"], dest=name, type=_flag_value(field.default),
                       default=field.default, help=field.metadata.get("help"), action=_Given)


def learner_hyperparameters(args) -> dict:
    """The registry's hyperparameters as parsed (field name -> value)."""
    from sern_jax.learners import registry

    return {name: getattr(args, name) for name in registry.hyperparameters()}


def flag_names(message: str) -> str:
    """An OnlineConfig error as the user typed it: setting names replaced by their flags
    (names already written as flags, ``--alpha``, are left alone)."""
    message = re.sub(r"(?<![-\w])(" + "|".join(_LEARN_FLAGS) + r")\b",
                     lambda m: _LEARN_FLAGS[m.group(1)], message)
    return re.sub(r"^p must", "--p must", message)


def _check_learn_values(args, policies: tuple[str, ...]) -> None:
    """The float flags of ``sern grasp learn`` as typed (before any float32 cast hides
    them): finite, in range, and representable as float32 normal numbers (``--alpha
    1e-300`` became 0 in float32, softmax returned NaN and SERN chose no grasp, exit 0)."""
    validate.finite_float(args.alpha, "--alpha", low=0, low_open=True, float32_normal=True)
    validate.finite_float(args.epsilon, "--epsilon", low=0, high=1, float32_normal=True)
    validate.finite_float(args.alpha0, "--alpha0", low=0, low_open=True, float32_normal=True)
    validate.finite_float(args.p, "--p", low=0, high=1, low_open=True, high_open=True)
    if "sern_log" in policies:
        import math

        horizon = args.rounds * args.explore
        if horizon < 2:
            raise ValueError(f"--policies sern_log needs --rounds x --explore >= 2 "
                             f"(α0/ln(T^p) at T = {horizon} is infinite)")
        alpha = args.alpha0 / (args.p * math.log(horizon))
        validate.finite_float(alpha, f"--alpha0 {args.alpha0:g} / ln(T^--p) (sern_log's α)",
                              low=0, low_open=True, float32_normal=True)


def _check_run_dir(out: Path, fingerprint: str) -> None:
    """The run directory, before anything is written (:func:`io.check_run_dir`, the check
    the regret commands make): its checkpoint (verified; a damaged file is named in one line)
    and its ``config.json`` must both hold this run's fingerprint, so another run's directory,
    a learn run's or any other command's, is left untouched, and the same settings resume."""
    from sern_jax.infra import io

    io.check_run_dir(out, fingerprint, what="learning run", checkpoint="checkpoint.npz",
                     advice="delete it to restart the run from round 0 (or choose another "
                            "--out)")


def check_learn_args(args, num_objects: int | None = None, bench=None):
    """What ``sern grasp learn`` can check before θ0 and the objects are loaded: the output
    paths, the float flags (:func:`_check_learn_values`), the OnlineConfig and, when the
    number of objects is known, the run's size (:mod:`sern_jax.grasp.online.budget`). Returns the
    OnlineConfig. ``sern reproduce`` calls it before its first part runs. With ``bench`` (a
    loaded benchmark, ``--benchmark``) the OnlineConfig is the benchmark's
    (:func:`_benchmark_config`)."""
    _check_out(args.out)
    from sern_jax.infra import io

    io.refuse_if_locked(args.out)  # a running learn there: refused before imports, compiles
    _check_file_out(args.json_out)
    if bench is not None:
        config = _benchmark_config(args, bench)
        if num_objects is not None:
            _check_learn_size(config, num_objects, args.out)
        return config
    policies = tuple(validate.comma_list(args.policies, "--policies"))
    _check_learn_values(args, policies)
    from sern_jax.grasp.online import config as online_config

    hyper = learner_hyperparameters(args)
    from sern_jax.learners import registry

    # every learner's float hyperparameter (UCB width, prior variance, ε/α schedules, ...):
    # finite and representable in float32 (its own range is its config's check, below)
    validate.float32_hyperparameters(
        hyper, {n: f.metadata["flag"] for n, f in registry.hyperparameters().items()})
    try:
        config = online_config.OnlineConfig(
            policies=policies, num_seeds=args.seeds, rounds=args.rounds,
            explore=args.explore, evaluate=args.evaluate, alpha=args.alpha,
            epsilon=args.epsilon, alpha0=args.alpha0, p=args.p, eval_poses=args.eval_poses,
            eval_trials=args.eval_trials, regret_trials=args.regret_trials,
            regret_grasps=args.regret_grasps,
            fit_steps=args.fit_steps, core_set=args.core_set, loss=args.loss, seed=args.seed,
            backend=getattr(args, "backend", "native"),
            hyper={k: v for k, v in hyper.items() if k not in ("alpha", "epsilon", "alpha0", "p")})
    except ValueError as e:
        raise ValueError(flag_names(str(e))) from None
    if num_objects is not None:
        _check_learn_size(config, num_objects, args.out)
    return config


# --benchmark: the flags whose settings a benchmark fixes (argparse dest -> what it fixes);
# the hyperparameter flags of the learners it tunes are refused too
_BENCHMARK_FIXES = {
    "explore": "protocol", "evaluate": "protocol", "eval_poses": "protocol",
    "eval_trials": "protocol", "fit_steps": "protocol", "core_set": "protocol",
    "loss": "protocol", "seed": "protocol", "mesh_units": "objects",
}


def _load_benchmark(args):
    """The benchmark ``--benchmark`` names (None without the flag): one line naming the
    flag and the known names for an unknown one, naming the file for a damaged one."""
    name = getattr(args, "benchmark", None)
    if name is None:
        return None
    from sern_jax.grasp.online import benchmark

    return benchmark.resolve(name, "--benchmark")


def _benchmark_config(args, bench):
    """The OnlineConfig of a ``--benchmark`` run (:func:`benchmark.online_config`): the
    flags the benchmark fixes are refused when typed (even with their default value),
    --policies, --seeds and --rounds choose learners and a smaller run, --backend,
    --regret-trials and --regret-grasps pass through, and the hyperparameter flags of
    learners the benchmark does not tune set those learners' values."""
    import dataclasses

    from sern_jax.grasp.online import benchmark
    from sern_jax.learners import registry

    given = dict(getattr(args, "given", None) or {})
    tuned = {f.name: name for name in bench.learners
             for f in dataclasses.fields(registry.LEARNERS[name].config)}
    for dest, flag in given.items():
        if dest in _BENCHMARK_FIXES:
            raise ValueError(f"{flag}: benchmark {bench.name} fixes its "
                             f"{_BENCHMARK_FIXES[dest]}; leave {flag} out")
        if dest in tuned:
            raise ValueError(f"{flag}: benchmark {bench.name} fixes the hyperparameters of "
                             f"the learners it tunes ({tuned[dest]}); leave {flag} out")
    if args.mesh:
        raise ValueError(f"--mesh: benchmark {bench.name} fixes the objects; name one of its "
                         "objects as OBJECT to run a part of it")
    policies = (tuple(validate.comma_list(args.policies, "--policies"))
                if "policies" in given else None)
    hyper = {dest: getattr(args, dest) for dest in given if dest in registry.hyperparameters()}
    validate.float32_hyperparameters(
        hyper, {n: f.metadata["flag"] for n, f in registry.hyperparameters().items()})
    try:
        config = benchmark.online_config(
            bench, policies, seeds=args.seeds if "seeds" in given else None,
            rounds=args.rounds if "rounds" in given else None, hyper=hyper)
        config = dataclasses.replace(
            config, backend=args.backend if "backend" in given else config.backend,
            regret_trials=args.regret_trials, regret_grasps=args.regret_grasps)
    except ValueError as e:  # --seeds / --rounds beyond the benchmark's, or OnlineConfig's
        size = re.match(r"(seeds|rounds) (must .*)", str(e))
        raise ValueError(f"--{size[1]} {size[2]}" if size else flag_names(str(e))) from None
    return config


def run_learn(args, make_figures: Callable | None = None, log=print) -> int:
    bench = _load_benchmark(args)  # None without --benchmark
    config = check_learn_args(args, bench=bench)
    from sern_jax.infra import distributed, io

    ray = distributed.from_args(args)  # None without --ray
    distributed.check_backend(config.backend, ray)  # mjx tasks on a GPU only
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.online import config as online_config
    from sern_jax.grasp.online import driver

    world = (None, None) if bench is None else bench.world
    if bench is not None:
        from sern_jax.grasp.online import benchmark
        from sern_jax.grasp.world import context as context_lib
        from sern_jax.grasp.world import sim as sim_lib

        if ray is not None and world != (context_lib.ContextConfig(), sim_lib.TrialConfig()):
            raise ValueError(f"--ray: benchmark {bench.name} changes the simulated world, "
                             "which Ray units do not carry; run it without --ray, one "
                             "object (a part) per command")
        specs = benchmark.select(bench, args.objects)
        _check_learn_size(config, len(specs), args.out)
    else:
        # named objects and meshes are checked before θ0 is loaded (a bad mesh is reported as
        # such even where θ0 is missing); the default objects come from θ0's screen
        explicit = bool(args.objects) or bool(args.mesh)
        units = getattr(args, "mesh_units", "auto")
        specs = _specs(args.objects, args.mesh, (), units) if explicit else None
        if specs is not None:  # sizes before θ0 is even loaded
            _check_learn_size(config, len(specs), args.out)
    theta0 = artifacts.load_theta0(args.theta0)
    if bench is not None:
        benchmark.check_theta0(bench, theta0,
                               None if args.theta0 is None else f"--theta0 {args.theta0}")
    if specs is None:
        specs = _specs((), (), artifacts.hard_set(theta0)["objects"])
        _check_learn_size(config, len(specs), args.out)
    t0 = time.perf_counter()
    fingerprint = online_config.run_fingerprint(config, specs, theta0)
    if bench is not None:  # a benchmark's world, as driver.run fingerprints it
        fingerprint = online_config.extend_fingerprint(
            fingerprint, config, tuple(range(config.num_seeds)), *world, ())
    out = Path(args.out) if args.out else Path("runs") / ("learn-" + fingerprint)
    _check_run_dir(out, fingerprint)
    record = None if bench is None else {
        "name": bench.name, "version": bench.version, "file": bench.path.name,
        "objects": [s.name for s in specs], "seeds": config.num_seeds,
        "rounds": config.rounds, "backend": config.backend}
    with validate.locked_run_dir(out):
        if ray is None:
            res = driver.run(config, specs, out, theta0=theta0,
                             progress=not args.no_progress, log=log,
                             context_config=world[0], trial_config=world[1])
        else:  # one Ray task per object, joined into the same run directory
            from sern_jax.grasp.online import learn_units

            res = learn_units.run(config, specs, out, theta0=theta0, ray=ray,
                                  progress=not args.no_progress, log=log)
        seconds = time.perf_counter() - t0
        write_learn_outputs(out, res, seconds, theta0, benchmark=record)
        table = format_table(res["table"])
        print(table)
        if not args.no_figures and make_figures is not None:
            for path in make_figures(out):
                print(f"wrote {path}")
    if args.json_out:
        io.save_json(args.json_out, {"table": res["table"], "seconds": seconds,
                                     "machine": io.run_metadata()["host"]})
    print(f"run directory: {out}  ({seconds:.0f} s)")
    return 0


def _check_learn_size(config, num_objects: int, out) -> None:
    from sern_jax.grasp.online import budget

    _check_size(budget.learn(
        objects=num_objects, policies=len(config.policies), seeds=config.num_seeds,
        rounds=config.rounds, explore=config.explore, evaluate=config.evaluate,
        eval_poses=config.eval_poses, eval_trials=config.eval_trials,
        regret_trials=config.regret_trials, fit_steps=config.fit_steps,
        batch_size=config.batch_size, regret_grasps=config.regret_grasps,
        network_copies=sum(config.hyperparameters().get("ensemble_size", 1)
                           if name == "ensemble_ts" else 1 for name in config.policies)), out)


def write_learn_outputs(out: Path, res: dict, seconds: float, theta0,
                        benchmark: dict | None = None) -> None:
    """config.json, metadata.json, results.npz, table.md/json, report.md of a learn run;
    ``benchmark`` (a ``--benchmark`` run: its name, version, file, and the objects, seeds,
    rounds and backend run) goes into config.json and metadata.json."""
    from sern_jax.infra import io

    extra = {} if benchmark is None else {"benchmark": benchmark}
    io.save_json(out / "config.json", {"config": res["config"], "objects": res["objects"],
                                       "theta0": theta0.fingerprint,
                                       "fingerprint": res["fingerprint"], **extra})
    io.save_json(out / "metadata.json", io.run_metadata(timings=res["timings"],
                                                         trial_counts=res["trial_counts"],
                                                         seconds=seconds, **extra))
    io.save_npz(out / "results.npz", **res["results"]._asdict())
    io.save_json(out / "table.json", {"table": res["table"], "seconds": seconds})
    table = format_table(res["table"])
    io.save_text(out / "table.md", table + "\n")
    t = res["timings"]
    split = ", ".join(f"{k} {v:.0f} s" for k, v in t.items())
    n = res["trial_counts"]
    shared = (f" Trials: {n['simulated']:,} simulated for {n['requested']:,} policy "
              "grasps (policies that pick the same grasp on the same pose share its "
              "trial: common random numbers)." if n["requested"] else "")
    io.save_text(out / "report.md",
                 f"# Online grasp learning\n\n{table}\n\nWall time {seconds:.0f} s. Time in each "
                 f"phase (a round's evaluation runs beside the next round's exploration, "
                 f"so they overlap; wait: the main thread waiting for an evaluation): "
                 f"{split}.{shared}\n")
