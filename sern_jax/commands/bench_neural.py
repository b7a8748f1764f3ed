"""``sern bench neural``: seed-rounds per second of the neural runner beside a per-seed Python
loop over the same JAX functions (:mod:`sern_jax.bench.neural`).

Default workload (issue 19): the wheel bandit at δ = 0.95, Neural-Linear Thompson sampling
on a one-hidden-layer MLP (50 units) updated every 50 rounds by 20 Adam steps of 64 rows,
1,000 seeds × 5,000 rounds. Compile time is reported apart; the Python loop runs
``--loop-seeds`` × ``--loop-rounds`` (its rate does not depend on the seed count).
"""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``neural`` under ``sern bench``."""
    from sern_jax.bench.neural import NeuralBenchConfig

    d = NeuralBenchConfig.__dataclass_fields__
    p = subparsers.add_parser(
        "neural",
        help="neural-learner throughput on the wheel bandit (jit(vmap(scan)) vs a Python loop)",
        description=__doc__.split("\n\n")[0] + " Prints one JSON object with --json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--learner", default=d["learner"].default, help="a learner registry name")
    p.add_argument("--delta", type=float, default=d["delta"].default, help="the wheel's δ")
    p.add_argument("--seeds", type=int, default=d["num_seeds"].default, help="S")
    p.add_argument("--horizon", type=int, default=d["horizon"].default, help="T")
    p.add_argument("--update-every", type=int, default=d["update_every"].default,
                   help="rounds between network updates")
    p.add_argument("--hidden", default=",".join(map(str, d["hidden"].default)),
                   help="MLP hidden widths, comma list")
    p.add_argument("--fit-steps", type=int, default=d["fit_steps"].default,
                   help="Adam steps per update")
    p.add_argument("--batch-size", type=int, default=d["batch_size"].default,
                   help="rows per Adam step")
    p.add_argument("--repeats", type=int, default=d["repeats"].default,
                   help="timed runs of the batched path (median; 0 skips it)")
    p.add_argument("--loop-seeds", type=int, default=d["loop_seeds"].default,
                   help="seeds of the Python-loop reference (0 skips it)")
    p.add_argument("--loop-rounds", type=int, default=d["loop_rounds"].default,
                   help="rounds per seed of the Python-loop reference")
    p.add_argument("--chunk-size", type=int, default=None,
                   help="seeds per compiled call (default: an equal share per core)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from sern_jax.bench import neural as neural_bench

    try:
        hidden = tuple(int(w) for w in args.hidden.split(",") if w.strip())
    except ValueError:
        raise ValueError(f"--hidden must be a comma list of integers, got {args.hidden!r}") \
            from None
    if not hidden or min(hidden) < 1:
        raise ValueError(f"--hidden widths must be >= 1, got {args.hidden!r}")
    config = neural_bench.NeuralBenchConfig(
        learner=args.learner, delta=args.delta, num_seeds=args.seeds, horizon=args.horizon,
        update_every=args.update_every, hidden=hidden, fit_steps=args.fit_steps,
        batch_size=args.batch_size, repeats=args.repeats, loop_seeds=args.loop_seeds,
        loop_rounds=args.loop_rounds, chunk_size=args.chunk_size)
    neural_bench.build(config)  # every check (δ, shapes) before anything compiles
    log = None if args.json else (lambda m: print(m, file=sys.stderr))
    result = neural_bench.run_bench(config, log=log)
    if args.json:
        print(json.dumps(result, default=float))
    else:
        b, loop = result.get("batched"), result.get("python_loop")
        print(f"machine: {result['machine']['cpu']} ({result['machine']['cores_usable']} "
              f"cores, {result['machine']['backend']})")
        print(f"compile: {result['batched_compile_s']:.1f} s")
        if b:
            print(f"batched jit(vmap(scan)): {b['seed_rounds_per_s']:.4g} seed-rounds/s "
                  f"({b['seconds']:.1f} s for {config.num_seeds} x {config.horizon})")
        if loop:
            print(f"per-seed Python loop:    {loop['seed_rounds_per_s']:.4g} seed-rounds/s")
        if "speedup" in result:
            print(f"speed-up: {result['speedup']:.1f}x")
    return 0
