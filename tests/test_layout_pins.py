"""Moving code between modules changes no result: the engines' and commands' outputs equal,
bit for bit, the digests in tests/data/layout_pins.json, which
tests/data/make_layout_pins.py wrote from the code before sern_jax was laid out by role.

The digests are of CPU results under the jax version the JSON names; under another version
XLA may round differently, so the test skips there instead of comparing."""

import json
import sys
from pathlib import Path

import jax
import pytest

DATA = Path(__file__).with_name("data")
sys.path.insert(0, str(DATA))
import make_layout_pins as pins  # noqa: E402

REFERENCE = json.loads((DATA / "layout_pins.json").read_text())


def _same_jax():
    if REFERENCE["jax"] != jax.__version__:
        pytest.skip(f"digests made under jax {REFERENCE['jax']}, this is {jax.__version__}")


def _compare(got: dict[str, str]) -> None:
    assert got, "nothing computed"
    want = {k: REFERENCE["pins"][k] for k in got}
    assert got == want


def test_run_seeds_outputs_are_unchanged():
    _same_jax()
    _compare(pins.engine_pins())


# the tabular regret run in the default suite; the neural regret run and the small learning run
# (half a minute each on 2 cores, their paths pinned also by tests/grasp/test_runner.py's
# reference and tests/test_neural_regret_cli.py) with -m slow
@pytest.mark.parametrize("name", [
    pytest.param(n, marks=() if n == "regret_tabular" else pytest.mark.slow)
    for n in sorted(pins.COMMANDS)])
def test_command_outputs_are_unchanged(name):
    _same_jax()
    _compare(pins.command_pins({name: pins.COMMANDS[name]}))


@pytest.mark.slow  # the full Table I setting of sern grasp learn: minutes on 2 cores
def test_table1_learning_run_is_unchanged():
    _same_jax()
    _compare(pins.command_pins(pins.SLOW_COMMANDS))


def test_a_changed_output_changes_its_digest():
    # control: the digest sees one flipped bit, a dtype and a shape
    import numpy as np

    a = np.arange(6, dtype=np.float32)
    b = a.copy()
    b.view(np.uint32)[3] ^= 1
    base = pins.digest_arrays({"x": a})
    assert base != pins.digest_arrays({"x": b})
    assert base != pins.digest_arrays({"x": a.astype(np.float64)})
    assert base != pins.digest_arrays({"x": a.reshape(2, 3)})
    assert base == pins.digest_arrays({"x": a.copy()})
