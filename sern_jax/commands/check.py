"""``sern check``: run the theory checks, print a table, write report.md + JSON + figures.

Exit status 0 iff every verdict equals its expectation: claims expected to hold did not FAIL,
and every negative control / counterexample did FAIL (a negative control that passes means the
harness is broken). Heavy imports (jax, the checks) happen inside ``run``.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import sys
import time


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``sern check`` on an argparse subparsers object."""
    p = subparsers.add_parser(
        "check",
        help="numerically check the paper's Theorems 1-5 (exit 0 iff all verdicts as expected)",
        description=(
            "Checks Theorems 1-5 of the SERN paper by exact computation and Monte Carlo with "
            "confidence intervals (see docs/THEORY.md). Each check declares its claim, "
            "statistic, bound and expected verdict (HOLDS, or FAILS for negative controls and "
            "counterexamples); the exit status is 0 iff every verdict is the expected one."
        ),
    )
    p.add_argument("--quick", action="store_true",
                   help="small sizes; part of the default test run")
    p.add_argument("--only", nargs="+", metavar="NAME", default=None,
                   help="run only these checks (names as in the table)")
    p.add_argument("--seeds", type=int, default=None, metavar="N",
                   help="override every check's number of seeds")
    p.add_argument("--json-out", default=None, metavar="FILE",
                   help="also write the JSON report to FILE")
    p.add_argument("--out", default="runs", metavar="DIR",
                   help="root of the run directory (default: runs/)")
    p.add_argument("--name", default=None, help="run directory name (default: check-<time>)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise error rate per check (default 0.01: 99%% one-sided)")
    p.add_argument("--seed", type=int, default=0, help="root seed")
    p.add_argument("--wrong-bounds", action="store_true",
                   help="harness self-test: use each check's deliberately wrong bound; every "
                        "verdict should then differ from its expectation")
    p.add_argument("--no-figures", action="store_true", help="skip writing figures/*.png")
    p.add_argument("--list", action="store_true", help="list the checks and exit")
    p.set_defaults(func=run)
    return p


_MAX_SEEDS = 10_000_000  # the largest checks hold O(seeds x horizon) floats per seed batch


def _validate(args) -> None:
    """Every option, before any check runs or anything is written."""
    if args.seeds is not None and not 2 <= args.seeds <= _MAX_SEEDS:
        raise ValueError(f"--seeds must lie in [2, {_MAX_SEEDS:,}], got {args.seeds}")
    if not 0.0 < args.alpha < 0.5:
        raise ValueError(f"--alpha must lie in (0, 0.5), got {args.alpha}")
    if not 0 <= args.seed <= 2**32 - 1:
        raise ValueError(f"--seed must lie in [0, 2^32 - 1], got {args.seed}")
    from sern_jax.infra import validate

    # tried for real (os.access says yes to root on /proc): nothing is left behind
    validate.out_dir(args.out, "--out")
    if args.name is not None and (not args.name or "/" in args.name or args.name in (".", "..")):
        raise ValueError(f"--name must be a plain directory name, got {args.name!r}")
    validate.out_file(args.json_out, "--json-out")


def run(args) -> int:
    """Entry point of ``sern check``; returns the exit status."""
    from sern_jax.commands.scripts import script_module

    registry = script_module("proofs_check", "registry")

    _validate(args)
    if args.list:
        for name in registry.NAMES:
            c = registry.get(name)
            print(f"{name:28s} expect {c.expected:5s}  {c.claim}")
        return 0
    try:  # unknown names, before any compile
        checks = registry.all_checks(args.only)
    except (KeyError, ValueError) as exc:
        raise ValueError(f"--only: {str(exc).strip(chr(39))} (sern check --list names "
                         "them)") from None

    from sern_jax.infra import validate

    with contextlib.ExitStack() as stack:
        if args.json_out:  # two checks into one --json-out: the second is refused
            stack.enter_context(_file_lock(args.json_out, "--json-out"))
        run_dir = stack.enter_context(validate.locked_run_dir(_new_run_dir(args)))
        (run_dir / "figures").mkdir(exist_ok=True)
        return _run(args, checks, run_dir, registry)


def _new_run_dir(args):
    """``--out/--name``, or a fresh ``check-<time>[-N]`` that no other run took (made with
    an exclusive ``mkdir``, so two checks started in the same second never share one)."""
    from pathlib import Path

    root = Path(args.out)
    if args.name:
        return root / args.name
    name = ("check-" + _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
            + ("-quick" if args.quick else ""))
    try:
        root.mkdir(parents=True, exist_ok=True)
        for i in range(1, 10_000):
            path = root / (name if i == 1 else f"{name}-{i}")
            try:
                path.mkdir()
                return path
            except FileExistsError:
                continue
    except OSError as exc:
        raise ValueError(f"--out {args.out}: cannot create the run directory "
                         f"({exc.strerror or exc})") from None
    raise ValueError(f"--out {args.out}: every run directory name {name}-N is taken")


@contextlib.contextmanager
def _file_lock(path, flag: str):
    """An exclusive ``flock`` on ``.<name>.lock`` beside ``path`` while the block runs; one
    line naming ``flag`` when another process holds it (its report would be lost)."""
    import fcntl
    import os
    from pathlib import Path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.parent / f".{path.name}.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise ValueError(f"{flag} {path} is being written by another sern check; wait "
                             "for it or choose another file") from None
        yield
    finally:
        os.close(fd)


def _run(args, checks, run_dir, registry) -> int:
    from tqdm import tqdm

    from sern_jax.commands.scripts import script_module
    from sern_jax.infra import io

    fw = script_module("proofs_check", "framework")
    report = script_module("proofs_check", "report")
    bar = tqdm(checks, desc="sern check", unit="check", file=sys.stderr,
               disable=None)
    ctx = fw.Context(quick=args.quick, seeds=args.seeds, alpha=args.alpha,
                     mutate=args.wrong_bounds, root_seed=args.seed,
                     progress=lambda msg: bar.set_postfix_str(msg[:60], refresh=True))
    t0 = time.perf_counter()
    results = []
    tty = sys.stderr.isatty()
    for i, check in enumerate(bar):
        bar.set_description(check.name)
        res = fw.run_check(check, ctx)
        results.append(res)
        if not tty:  # tqdm is silent off a terminal: leave one line per check in the log
            print(f"[{i + 1}/{len(checks)}] {check.name}: {res.verdict} (expected "
                  f"{res.expected}) {res.wall_s:.0f} s", file=sys.stderr, flush=True)
    total = time.perf_counter() - t0
    bar.close()

    command = "sern check " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["check"] else "sern check"
    doc = report.build_json(results, args, total, command)
    io.save_json(run_dir / "report.json", doc)
    io.save_json(run_dir / "config.json", doc["options"])
    io.save_json(run_dir / "metadata.json", doc["metadata"])
    io.save_json(run_dir / "figure_data.json", {r.name: r.figure_data for r in results})
    (run_dir / "report.md").write_text(report.build_markdown(results, doc))
    if args.json_out:
        io.save_json(args.json_out, doc)
    print(report.table(results))
    figs_note = ""
    if not args.no_figures:
        try:
            make_theory_figs = script_module("figures", "make_theory_figs")
            made = make_theory_figs.make_all(run_dir)
            figs_note = f", {len(made)} figures"
        except Exception as exc:  # figures must never hide the verdicts
            figs_note = f", figures failed: {exc!r}"
    ok = all(r.ok for r in results)
    print(f"\n{sum(r.ok for r in results)}/{len(results)} verdicts as expected in {total:.0f} s"
          f"{figs_note}; report: {run_dir / 'report.md'}")
    if args.wrong_bounds:
        print("(--wrong-bounds: deliberately wrong bounds were used; verdicts should differ "
              "from the expectations)")
    return 0 if ok else 1
