"""Checks every command makes before any work: one line naming the flag, exit 2, nothing
written (the bad-input promise of README and DESIGN).

* :class:`OneLineParser`: argparse's errors as one line ``sern ...: error: <message>`` (no
  usage block); ``--help`` is unchanged. Subparsers inherit the class, so every subcommand
  of the ``sern`` parser reports errors this way.
* :func:`out_dir` / :func:`out_file`: an output path is tried for real (a directory chain
  made and removed, a temporary file created and removed in the first existing ancestor), so
  ``/proc/x``, a read-only mount or a file where a directory must go are refused up front
  (``os.access`` says yes to root on ``/proc``).
* :func:`script_parser`: the same parser for the experiment scripts (``python -m
  experiments.NAME``, ``sern experiment NAME``), named as the user ran it; :func:`int_at_least`:
  an integer flag's argparse ``type`` with a floor (``--seeds abc``, ``--seeds -1``: one line
  ``... error: argument --seeds: ...``, exit 2, before anything is imported or compiled).
* :func:`finite_float`: a float flag that must be finite and in range; ``float32_normal``
  refuses values that float32 cannot hold as a normal number (``--alpha 1e-300`` became 0 in
  float32, softmax returned NaN and SERN picked no grasp, with exit 0).
* :func:`locked_run_dir`: the run directory's lock (``io.run_lock``), removing a directory it
  created if the run fails before writing anything else.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

__all__ = [
    "FLOAT32_TINY",
    "OneLineParser",
    "finite_float",
    "float32_hyperparameters",
    "int_at_least",
    "locked_run_dir",
    "out_dir",
    "out_file",
    "script_parser",
]

FLOAT32_TINY = float(np.finfo(np.float32).tiny)  # smallest normal float32, 1.1754944e-38
FLOAT32_MAX = float(np.finfo(np.float32).max)  # 3.4028235e38


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr, exit status 2."""

    def error(self, message: str):  # argparse's hook
        message = " ".join(str(message).split())
        sys.stderr.write(f"{self.prog}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def script_parser(spec=None, **kwargs) -> OneLineParser:
    """The :class:`OneLineParser` of an experiment script's ``main``.

    Its ``prog`` is how the user ran the script: ``sern experiment NAME`` (the name that
    command puts in ``sys.argv[0]``), else ``python -m <module>`` (the module's name from
    its ``__spec__``; without one, a file run as ``python experiments/NAME.py``, argparse's
    default, the file's name). Subparsers inherit the class, so their errors are one line
    too; ``--help`` is unchanged.

    Args:
      spec: the script's ``__spec__`` (a ``ModuleSpec`` or None) or its module name.
      **kwargs: passed on to ``argparse.ArgumentParser`` (``description``, ...).
    """
    module = spec if isinstance(spec, str) or spec is None else spec.name
    if "prog" not in kwargs:
        argv0 = sys.argv[0] if sys.argv else ""
        if argv0.startswith("sern experiment "):
            kwargs["prog"] = argv0
        elif module and module != "__main__":
            kwargs["prog"] = f"python -m {module}"
    return OneLineParser(**kwargs)


def int_at_least(low: int):
    """An argparse ``type``: an integer >= ``low``. A bad value is argparse's one-line error
    naming the flag (``argument --seeds: must be >= 1, got -1``), raised while parsing."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


def finite_float(value: float, flag: str, *, low: float | None = None,
                 high: float | None = None, low_open: bool = False, high_open: bool = False,
                 float32_normal: bool = False) -> float:
    """``value`` if finite and in [low, high] (open ends as asked), else ``ValueError``
    naming ``flag``. ``float32_normal``: a nonzero value must also be at least float32's
    smallest normal number in magnitude (it is used in float32 arithmetic)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        # a ValueError, not a TypeError: the commands turn ValueError into exit 2
        raise ValueError(f"{flag} must be a number, got {value!r}")  # noqa: TRY004
    value = float(value)
    lo_text = "-inf" if low is None else f"{low:g}"
    hi_text = "inf" if high is None else f"{high:g}"
    span = f"{'(' if low_open else '['}{lo_text}, {hi_text}{')' if high_open else ']'}"
    if not math.isfinite(value):
        where = "" if low is None and high is None else f" in {span}"
        raise ValueError(f"{flag} must be a finite number{where}, got {value!r}")
    if low is not None and (value < low or (low_open and value == low)):
        raise ValueError(f"{flag} must lie in {span}, got {value:g}")
    if high is not None and (value > high or (high_open and value == high)):
        raise ValueError(f"{flag} must lie in {span}, got {value:g}")
    if float32_normal and value != 0 and abs(value) < FLOAT32_TINY:
        raise ValueError(
            f"{flag} {value:g} is below float32's smallest normal number ({FLOAT32_TINY:.4g}): "
            "float32 arithmetic would make it 0 or a denormal (a temperature of 0 makes "
            f"softmax NaN); use 0 or a value >= {FLOAT32_TINY:.4g}")
    if float32_normal and abs(value) > FLOAT32_MAX:
        raise ValueError(f"{flag} {value:g} is beyond float32's largest number "
                         f"({FLOAT32_MAX:.4g}): it would be computed as infinity")
    return value


def float32_hyperparameters(values: dict, flags: dict) -> None:
    """Every float among ``values`` (name -> value) finite and representable in float32 as
    0 or a normal number, named by ``flags`` (name -> flag): what the learners' float32
    arithmetic needs whatever their own ranges (a learner's config checks those)."""
    for name, value in values.items():
        if isinstance(value, float):
            finite_float(value, flags.get(name, name), float32_normal=True)


def _first_existing(path: Path) -> Path:
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def _probe_write(directory: Path, flag: str, path) -> None:
    """Creates and removes a temporary file in ``directory``; ValueError naming ``flag``."""
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".sern-write-test-")
    except OSError as exc:
        raise ValueError(f"{flag} {path}: cannot write in {directory} "
                         f"({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(tmp)


def out_dir(path: str | os.PathLike | None, flag: str = "--out") -> None:
    """Refuses an output directory that cannot be created or written, before any work.

    Makes the missing part of the path and a temporary file in it, then removes both:
    nothing is left behind whether it succeeds or not.
    """
    if path is None:
        return
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise ValueError(f"{flag} {path} exists and is not a directory")
        _probe_write(p, flag, path)
        return
    made = []
    try:
        for parent in reversed([p, *p.parents]):
            if not parent.exists():
                parent.mkdir()
                made.append(parent)
        _probe_write(p, flag, path)
    except OSError as exc:
        raise ValueError(f"{flag} {path}: cannot create this directory "
                         f"({exc.strerror or exc})") from None
    finally:
        for d in reversed(made):
            with contextlib.suppress(OSError):
                d.rmdir()


def out_file(path: str | os.PathLike | None, flag: str = "--json-out") -> None:
    """Refuses an output file that could not be written, before any work (writes nothing
    that stays): not a directory, and a temporary file can be made where it would go (its
    nearest existing ancestor directory, as the atomic write creates the rest)."""
    if not path:
        return
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{flag} {path} is a directory; name a file")
    if p.exists() and not p.is_file():
        raise ValueError(f"{flag} {path} exists and is not a regular file")
    probe = _first_existing(p.parent if str(p.parent) else Path("."))
    if not probe.is_dir():
        raise ValueError(f"{flag} {path}: {probe} is not a directory")
    _probe_write(probe, flag, path)


@contextlib.contextmanager
def locked_run_dir(path: str | os.PathLike, command: str | None = None) -> Iterator[Path]:
    """``io.run_lock(path)``; if this call created the directory and the block fails before
    anything but the lock file was written, the directory is removed again."""
    from sern_jax.infra import io

    path = Path(path)
    created = not path.exists()
    try:
        with io.run_lock(path, command=command):
            yield path
    except BaseException:
        if created and path.is_dir():
            left = [c.name for c in path.iterdir() if c.name not in (io.LOCK_FILE, "figures")]
            figures = path / "figures"
            if not left and not (figures.is_dir() and any(figures.iterdir())):
                shutil.rmtree(path, ignore_errors=True)
        raise
