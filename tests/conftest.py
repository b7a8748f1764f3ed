"""Test configuration shared by all tests."""

import os
import shutil
import tempfile
from pathlib import Path

import hypothesis
import jax
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")


# ---------------------------------------------------------------- one compile per program
# Most of the suite's time is XLA compilation, and many tests build the same program again:
# each `sern` command run in-process makes new closures, a test file rebuilds a learner another
# test built, the other xdist worker or a subprocess compiles what this one did. One persistent
# compilation cache per test run, in a temporary directory made for the run and removed after
# it, lets each later compile of an identical program (the same HLO, compile options, jax and
# XLA versions) load the executable XLA made the first time: the same executable, so the same
# results, bit for bit. The workers and subprocesses find the directory in the environment.
CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"
_made_cache = []


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # the controller, or the only process (-n 0)
        path = tempfile.mkdtemp(prefix="sern-test-xla-cache-")
        _made_cache.append(path)
        os.environ[CACHE_ENV] = path  # read by the workers it starts and by subprocesses
    if os.environ.get(CACHE_ENV):  # (a worker started elsewhere compiles everything itself)
        jax.config.update("jax_compilation_cache_dir", os.environ[CACHE_ENV])


def pytest_unconfigure(config):
    for path in _made_cache:
        shutil.rmtree(path, ignore_errors=True)

hypothesis.settings.register_profile(
    "ci", deadline=None, derandomize=True, max_examples=50, print_blob=True
)
hypothesis.settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# ------------------------------------------------------------------------------ pytest-xdist
# The default run (pyproject addopts: -n 2 --dist loadfile --no-loadscope-reorder) spreads the
# suite over two worker processes. Most of its time is single-threaded XLA compilation, and a
# compiled program, a module fixture or a session fixture is shared only inside one process, so
# each test file goes to one worker whole (loadfile). Files start heaviest first (HEAVY: the
# longest files of the serial run), so no long file starts last while the other worker idles;
# the rest keep their collection order. (xdist's loadgroup, which could put files sharing a
# session fixture together, does not group under pytest 9.2: it rewrites item._nodeid, which
# pytest 9 no longer reads. Only tests/grasp/test_dataset.py and test_pretrain.py share one,
# tiny_dataset, and may each make it.) With `-n 0` (one process) none of this applies.
HEAVY = [  # longest first (the idle CI run's --durations, 2 cores)
    "tests/test_proofs_check.py",  # the quick checks: ~125 s
    "tests/test_distributed.py",  # local Ray: ~2 min
    "tests/grasp/test_runner.py",
    "tests/learners/test_engine_contract.py",  # every learner through the neural engine
    "tests/grasp/test_mjx_one_program.py",  # one MJX compile on the CPU, D0 shards on it
    "tests/grasp/test_benchmark.py",  # benchmark learn runs: ~85 s
    "tests/test_simulate.py",
    "tests/grasp/test_sim.py",
    "tests/grasp/test_asktell.py",
    "tests/test_neural_runner.py",
    "tests/learners/test_baseline_learners.py",
    "tests/test_neural_linear_arms.py",
    "tests/test_cli_fuzz.py",
    "tests/test_validation.py",
    "tests/test_executor.py",
    "tests/test_docs_examples.py",
    "tests/test_layout_pins.py",
]


def pytest_collection_modifyitems(config, items):
    if not hasattr(config, "workerinput"):  # the controller, or no xdist
        return
    rank = {name: i for i, name in enumerate(HEAVY)}

    def heavy_first(item):
        return rank.get(Path(os.path.relpath(item.path, config.rootpath)).as_posix(), len(HEAVY))

    items.sort(key=heavy_first)  # stable: a file's tests keep their order
