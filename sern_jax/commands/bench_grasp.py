"""``sern bench grasp``: throughput of the grasp pipeline, one JSON object.

The measurements (trials/s per backend and batch, depth images/s, candidate sets/s,
contexts/s, a time split per stage, the quality network's rates, with ``--objects a,b,c``
trials/s of that batch of objects per backend and ``mjx_compiles`` (MJX: one compiled
program over objects x trials), with ``--dataset-objects N`` D0 generation of N objects per
backend side by side, under ``"dataset"``, and with ``--agreement N`` the paired native-vs-MJX
agreement) are :mod:`sern_jax.bench.grasp` (``grasp_benchmark``, ``objects_benchmark``,
``dataset_benchmark``, ``measure_agreement``); this module parses and checks the flags, calls them, prints the
JSON and writes ``--out``. Every figure is measured in this run on this machine
(``machine`` in the output).
"""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_parser", "run", "main"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``grasp`` under the ``sern bench`` subcommands."""
    p = subparsers.add_parser(
        "grasp",
        help="grasp simulator throughput (trials/s per backend, depth, candidates)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print only the JSON object")
    p.add_argument(
        "--object", default="small_box", help="object name or .obj/.stl path"
    )
    p.add_argument("--native-batch", default="64,256", help="native batch sizes (csv)")
    p.add_argument(
        "--mjx-batch", default="16,64", help="MJX batch sizes (csv); '' skips"
    )
    p.add_argument("--depth-batch", type=int, default=16, help="images per depth call")
    p.add_argument(
        "--context-poses",
        default="16",
        help="poses per context.make_contexts call for contexts/s (csv); '' skips",
    )
    p.add_argument("--threads", type=int, default=None, help="native threads")
    p.add_argument("--repeats", type=int, default=2, help="timed calls per setting")
    p.add_argument(
        "--agreement",
        type=int,
        default=0,
        help="paired native/MJX trials per object (0 = skip)",
    )
    p.add_argument(
        "--agreement-objects",
        default="small_box,sphere,capsule,l_shape,cylinder,triangular_prism",
        help="objects for --agreement (csv)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="small sizes: native 32, MJX 8, depth 4, contexts 4, 1 repeat",
    )
    p.add_argument("--quality-sets", type=int, default=16,
                   help="64-candidate sets per quality-network scoring call (0 = skip)")
    p.add_argument("--quality-batch", type=int, default=64,
                   help="minibatch of the quality-network training-step timing")
    p.add_argument("--objects", default="",
                   help="a batch of objects (csv) timed per backend, MJX as one program over "
                        "objects x trials (reports mjx_compiles); trials per object: the largest "
                        "--mjx-batch")
    p.add_argument("--mjx-reference", action="store_true",
                   help="with --objects: also time the batch with MJX's own assembly of the "
                        "Newton Hessian (a second compile) beside the per-contact block "
                        "assembly every MJX trial uses; reports mjx_speedup and the paired "
                        "agreement of the two")
    p.add_argument("--dataset-objects", type=int, default=0,
                   help="generate a D0 slice of this many objects per backend (temporary "
                        "directories) and report seconds, trials/s, the host-contexts / trials "
                        "split and projections to the default and a Dex-Net-scale D0 "
                        "(0 = skip)")
    p.add_argument("--dataset-poses", type=int, default=16,
                   help="poses per object of --dataset-objects")
    p.add_argument("--dataset-backends", default="native,mjx",
                   help="backends of --dataset-objects (csv of native, mjx)")
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    p.set_defaults(func=run)
    return p


_MAX_BATCH = 65_536  # trials or poses per call: far above any useful benchmark size


def _csv_ints(text: str, name: str) -> list[int]:
    if not text.strip():
        return []
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError as e:
        raise ValueError(f"{name} must be comma-separated ints, got {text!r}") from e
    if min(values) < 1 or max(values) > _MAX_BATCH:
        raise ValueError(f"{name} values must lie in [1, {_MAX_BATCH}], got {text!r}")
    return values


def _dataset_backends(text: str) -> tuple[str, ...]:
    names = [n.strip() for n in text.split(",")]
    allowed = ("native", "mjx")
    if (not all(names) or len(set(names)) != len(names)
            or any(n not in allowed for n in names)):
        raise ValueError(f"--dataset-backends must be distinct comma-separated names of "
                         f"{', '.join(allowed)}, got {text!r}")
    return tuple(names)


def _validate(args) -> None:
    """Every option, before any benchmarking (also those that ``--quick`` replaces)."""
    for flag, text in (("--native-batch", args.native_batch), ("--mjx-batch", args.mjx_batch),
                       ("--context-poses", args.context_poses)):
        _csv_ints(text, flag)
    if not args.native_batch.strip():
        raise ValueError("--native-batch must name at least one batch size")
    for flag, value, low, high in (("--depth-batch", args.depth_batch, 1, 4096),
                                   ("--repeats", args.repeats, 1, 1000),
                                   ("--agreement", args.agreement, 0, 100_000),
                                   ("--quality-sets", args.quality_sets, 0, 100_000),
                                   ("--quality-batch", args.quality_batch, 1, _MAX_BATCH)):
        if not low <= value <= high:
            raise ValueError(f"{flag} must lie in [{low}, {high}], got {value}")
    for flag, value, low, high in (("--dataset-objects", args.dataset_objects, 0, 100_000),
                                   ("--dataset-poses", args.dataset_poses, 1, 1024)):
        if isinstance(value, bool) or not low <= value <= high:
            raise ValueError(f"{flag} must lie in [{low}, {high}], got {value}")
    _dataset_backends(args.dataset_backends)
    if args.threads is not None and not 1 <= args.threads <= 4096:
        raise ValueError(f"--threads must lie in [1, 4096], got {args.threads}")
    if args.out is not None:
        from sern_jax.infra import validate

        validate.out_file(args.out, "--out")  # a temporary file is tried where it would go
    if args.objects.strip():
        from sern_jax.grasp.world import objects as objects_lib

        names = args.objects.split(",")
        if not all(names) or len(set(names)) != len(names):
            raise ValueError(f"--objects must be distinct comma-separated names, got "
                             f"{args.objects!r}")
        for n in names:
            try:
                objects_lib.resolve_object(n)
            except (ValueError, OSError) as e:
                raise ValueError(f"--objects: {e}") from None
    if args.mjx_reference and not args.objects.strip():
        raise ValueError("--mjx-reference times the --objects batch: name --objects too")
    if args.agreement:
        from sern_jax.grasp.world import objects as objects_lib

        names = [n for n in args.agreement_objects.split(",") if n]
        if not names:
            raise ValueError("--agreement-objects is empty")
        for n in names:
            try:
                objects_lib.resolve_object(n)
            except ValueError as e:
                raise ValueError(f"--agreement-objects: {e}") from None


def run(args) -> int:
    _validate(args)  # before the heavy imports: a bad flag is refused in a second
    from sern_jax.commands.grasp_show import import_mjx_quietly

    import_mjx_quietly()
    from sern_jax.bench import grasp as benchmarks
    from sern_jax.grasp.world import objects as objects_lib

    try:
        quick = args.quick
        cfg = benchmarks.GraspBenchConfig(
            object=args.object,
            native_batches=(32,) if quick else tuple(_csv_ints(args.native_batch,
                                                               "--native-batch")),
            mjx_batches=(8,) if quick else tuple(_csv_ints(args.mjx_batch, "--mjx-batch")),
            depth_batch=4 if quick else args.depth_batch,
            context_poses=(4,) if quick else tuple(_csv_ints(args.context_poses,
                                                             "--context-poses")),
            threads=args.threads, repeats=1 if quick else args.repeats,
            quality_sets=args.quality_sets, quality_batch=args.quality_batch,
            objects=tuple(n for n in args.objects.split(",") if n),
            objects_trials=8 if quick else max(_csv_ints(args.mjx_batch, "--mjx-batch")
                                               or [64]),
            mjx_reference=args.mjx_reference)
        try:
            objects_lib.resolve_object(args.object)
        except (ValueError, OSError) as e:
            raise ValueError(f"--object: {e}") from None
    except ValueError as e:
        print(f"sern bench grasp: {e}", file=sys.stderr)
        return 2

    def log(msg):
        if not args.json:
            print(msg, file=sys.stderr, flush=True)

    out = benchmarks.grasp_benchmark(cfg, log)
    if args.agreement:
        names = [n for n in args.agreement_objects.split(",") if n]
        out["agreement"] = benchmarks.measure_agreement(
            names,
            args.agreement,
            progress=lambda n, s: log(
                f"agreement {n}: {s['agreement']:.3f} "
                f"(native {s['success_native']:.2f}, "
                f"mjx {s['success_mjx']:.2f})"
            ),
        )
        log(f"agreement overall: {out['agreement']['agreement']:.3f}")
    if args.dataset_objects:
        out["dataset"] = benchmarks.dataset_benchmark(
            args.dataset_objects, args.dataset_poses, _dataset_backends(args.dataset_backends),
            log)

    text = json.dumps(out, indent=None if args.json else 2, default=float)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


def main(argv=None) -> int:
    """``python -m sern_jax.commands.bench_grasp grasp ...`` (the same as ``sern bench grasp ...``)."""
    parser = argparse.ArgumentParser(prog="sern bench")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
