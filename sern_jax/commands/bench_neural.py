"""``sern bench neural``: seed-rounds per second of the neural runner beside a per-seed Python
loop over the same JAX functions (:mod:`sern_jax.bench.neural`).

Default workload: the wheel bandit at δ = 0.95, Neural-Linear Thompson sampling
on a one-hidden-layer MLP (50 units) updated every 50 rounds by 20 Adam steps of 64 rows,
1,000 seeds × 5,000 rounds. Compile time is reported apart; the Python loop runs
``--loop-seeds`` × ``--loop-rounds`` (its rate does not depend on the seed count).
"""

from __future__ import annotations

import argparse
import json
import sys

from sern_jax.infra import validate

__all__ = ["add_parser", "run"]


_MAX = 2**24  # seeds, rounds or a chunk per call: far above any useful benchmark size
_MAX_SEED_ROUNDS = 1e11


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
    p.add_argument("--delta", type=validate.float_in(0.0, 1.0, low_open=True, high_open=True),
                   default=d["delta"].default, help="the wheel's δ, in (0, 1)")
    p.add_argument("--seeds", type=validate.int_in(1, _MAX), default=d["num_seeds"].default,
                   help="S")
    p.add_argument("--horizon", type=validate.int_in(1, _MAX), default=d["horizon"].default,
                   help="T")
    p.add_argument("--update-every", type=validate.int_in(1, _MAX),
                   default=d["update_every"].default,
                   help="rounds between network updates")
    p.add_argument("--hidden", default=",".join(map(str, d["hidden"].default)),
                   help="MLP hidden widths, comma list")
    p.add_argument("--fit-steps", type=validate.int_in(1, 100_000),
                   default=d["fit_steps"].default, help="Adam steps per update")
    p.add_argument("--batch-size", type=validate.int_in(1, 1_000_000),
                   default=d["batch_size"].default, help="rows per Adam step")
    p.add_argument("--repeats", type=validate.int_in(0, 1000), default=d["repeats"].default,
                   help="timed runs of the batched path (median; 0 skips it)")
    p.add_argument("--loop-seeds", type=validate.int_in(0, 100_000),
                   default=d["loop_seeds"].default,
                   help="seeds of the Python-loop reference (0 skips it)")
    p.add_argument("--loop-rounds", type=validate.int_in(1, _MAX),
                   default=d["loop_rounds"].default,
                   help="rounds per seed of the Python-loop reference")
    p.add_argument("--chunk-size", type=validate.int_in(1, _MAX), default=None,
                   help="seeds per compiled call (default: an equal share per core)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    hidden = tuple(validate.comma_list_of(args.hidden, "--hidden", int, "integers",
                                          unique=False))
    if min(hidden) < 1 or max(hidden) > 4096:
        raise ValueError(f"--hidden widths must lie in [1, 4096], got {args.hidden!r}")
    if args.seeds * args.horizon > _MAX_SEED_ROUNDS:
        raise ValueError(f"--seeds {args.seeds} x --horizon {args.horizon} is over "
                         f"{_MAX_SEED_ROUNDS:.0e} seed-rounds, beyond any useful benchmark; "
                         "use fewer")
    from sern_jax.bench import neural as neural_bench

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
