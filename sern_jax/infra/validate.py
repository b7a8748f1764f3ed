"""Checks every command makes before any work: one line naming the flag, exit 2, nothing
written (the promise every command makes on bad input).

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
  refuses values that float32 cannot hold as a normal number (``--alpha 1e-300`` is 0 in
  float32, where softmax returns NaN and SERN would pick no grasp, with exit 0).
* Typed argparse ``type`` parsers (argparse turns their error into one line naming the flag,
  exit 2, before anything is imported or compiled): :func:`int_in` (an integer in a range),
  :func:`float_in` (a finite float in a range), :func:`comma_list` / :func:`comma_list_of`
  (a comma list with no empty items and no duplicates), :func:`ray_address` (``auto``,
  ``host:port`` or ``ray://host:port`` with a port in [1, 65535]).
* :func:`refuse_unused`: a flag given in a mode where it has no effect is refused, naming
  the flag and the mode (a flag that does nothing is a mistake the user wants to hear about).
* :func:`read_json_object`: a JSON file the project reads, refused in one line naming the
  file when it is unreadable or not an object with the fields and types asked for.
* :func:`quiet_numerics`: NumPy's floating-point warnings kept out of one-line errors.
* :func:`locked_run_dir`: the run directory's lock (``io.run_lock``), created and locked in
  one step; a directory this call created is removed again, under the lock, if the run fails
  before writing anything else.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

__all__ = [
    "FLOAT32_MAX",
    "FLOAT32_TINY",
    "INT32_MAX",
    "OneLineParser",
    "comma_list",
    "comma_list_of",
    "finite_float",
    "float32_hyperparameters",
    "float_in",
    "int_at_least",
    "int_in",
    "locked_run_dir",
    "out_dir",
    "out_file",
    "quiet_numerics",
    "ray_address",
    "read_json_object",
    "refuse_unused",
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
    too; ``--help`` is unchanged. Like the ``sern`` entry point, it turns on XLA's
    deterministic GPU options (:func:`sern_jax.infra.hosts.use_deterministic_xla`) before the
    script computes anything, so a rerun on a GPU gives the same bits.

    Args:
      spec: the script's ``__spec__`` (a ``ModuleSpec`` or None) or its module name.
      **kwargs: passed on to ``argparse.ArgumentParser`` (``description``, ...).
    """
    from sern_jax.infra import hosts

    hosts.use_deterministic_xla()
    module = spec if isinstance(spec, str) or spec is None else spec.name
    if "prog" not in kwargs:
        argv0 = sys.argv[0] if sys.argv else ""
        if argv0.startswith("sern experiment "):
            kwargs["prog"] = argv0
        elif module and module != "__main__":
            kwargs["prog"] = f"python -m {module}"
    return OneLineParser(**kwargs)


INT32_MAX = 2**31 - 1  # no count, size or seed of the project goes beyond int32


def int_in(low: int, high: int | None = None):
    """An argparse ``type``: an integer in [low, high] (no upper end when None). A bad value
    is argparse's one-line error naming the flag (``argument --seeds: must be an integer >= 1,
    got -1``), raised while parsing."""

    def parse(text: str) -> int:
        try:
            value = int(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if high is None or high == INT32_MAX:  # a floor, and int32's end as a ceiling
            if value < low:
                raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
            if high is not None and value > high:
                raise argparse.ArgumentTypeError(f"must be <= {high} (int32), got {value}")
        elif not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"must be an integer in [{low}, {high}], got {value}")
        return value

    parse.__name__ = f"integer >= {low}" if high is None else f"integer in [{low}, {high}]"
    return parse


def int_at_least(low: int, high: int | None = INT32_MAX):
    """An argparse ``type``: an integer >= ``low`` and, by default, at most int32's largest
    (a count of 10^20 is a typo, never a run; every array index of the project is int32)."""
    return int_in(low, high)


def float_in(low: float | None = None, high: float | None = None, *, low_open: bool = False,
             high_open: bool = False, float32_normal: bool = False):
    """An argparse ``type``: a finite float in the range (:func:`finite_float`'s checks).
    ``--alpha nan``, ``--alpha 1e400``, ``--epsilon 2`` are argparse's one-line error
    naming the flag."""

    def parse(text: str) -> float:
        try:
            value = float(text.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        try:
            return finite_float(value, "the value", low=low, high=high, low_open=low_open,
                                high_open=high_open, float32_normal=float32_normal)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("the value ")) from None

    parse.__name__ = "number"
    return parse


def comma_list(text: str, flag: str, *, unique: bool = True, allow_empty: bool = False,
               choices=None) -> list[str]:
    """The items of a comma list, stripped; ``ValueError`` naming ``flag`` for an empty
    item (``0.5,,0.7``: a typo, never dropped silently), a duplicate, an empty list (unless
    ``allow_empty``) or an item outside ``choices``."""
    if not isinstance(text, str):
        raise ValueError(f"{flag} must be a comma list, got {text!r}")  # noqa: TRY004
    if not text.strip():
        if allow_empty:
            return []
        raise ValueError(f"{flag} is empty; give a comma list")
    items = [item.strip() for item in text.split(",")]
    if any(not item for item in items):
        raise ValueError(f"{flag} {text!r} has an empty item (two commas in a row, or a comma "
                         "at an end)")
    if unique:
        seen = set()
        for item in items:
            if item in seen:
                raise ValueError(f"{flag} {text!r} lists {item!r} twice")
            seen.add(item)
    if choices is not None:
        for item in items:
            if item not in choices:
                raise ValueError(f"{flag}: unknown item {item!r}; choose from "
                                 f"{', '.join(map(str, choices))}")
    return items


def comma_list_of(text: str, flag: str, convert, what: str, *, unique: bool = True,
                  allow_empty: bool = False) -> list:
    """:func:`comma_list` with each item converted by ``convert`` (``int``, ``float``):
    ``ValueError`` naming ``flag`` and ``what`` (``"integers"``) for an item it refuses;
    duplicates are compared after conversion (``0.5,0.50``)."""
    items = comma_list(text, flag, unique=False, allow_empty=allow_empty)
    try:
        values = [convert(item) for item in items]
    except (ValueError, OverflowError):
        raise ValueError(f"{flag} must be a comma list of {what}, got {text!r}") from None
    if unique and len(set(values)) != len(values):
        raise ValueError(f"{flag} {text!r} lists a value twice")
    return values


def ray_address(text: str) -> str:
    """An argparse ``type`` for ``--ray ADDRESS``: ``auto``, ``local``, ``host:port`` or
    ``ray://host:port``, with a port in [1, 65535]; anything else is one line naming the
    flag before Ray is imported."""
    value = text.strip()
    if value in ("auto", "local"):
        return value
    rest = value.removeprefix("ray://")
    host, sep, port = rest.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or any(c.isspace() or c in "/@" for c in host):
        raise argparse.ArgumentTypeError(
            f"expected 'auto' or host:port (or ray://host:port), got {text!r}")
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"the port of {text!r} is not a number") from None
    if not 1 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"the port of {text!r} must lie in [1, 65535]")
    return value


def refuse_unused(args, defaults: dict, mode: str) -> None:
    """Refuses every flag among ``defaults`` (argparse dest -> its default) whose value in
    ``args`` differs from its default: in ``mode`` (``"with the tabular estimators"``) it has
    no effect. One line naming the first such flag (``ValueError``)."""
    for dest, default in defaults.items():
        value = getattr(args, dest, default)
        if value != default and not (isinstance(value, float) and isinstance(default, float)
                                     and math.isnan(value) and math.isnan(default)):
            raise ValueError(f"--{dest.replace('_', '-')} has no effect {mode}; leave it out")


@contextlib.contextmanager
def quiet_numerics() -> Iterator[None]:
    """NumPy's floating-point warnings (overflow, invalid) silenced: host-side checks turn
    such values into one line naming the flag, so the warning would only add lines."""
    import warnings

    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


_JSON_TYPES = {dict: "an object", list: "a list", str: "a string", int: "an integer",
               float: "a number", bool: "true or false"}


def read_json_object(path: str | os.PathLike, fields: dict | None = None, *,
                     what: str = "file", advice: str = "delete it or point at another") -> dict:
    """The JSON object in ``path``, checked against a schema.

    ``fields`` maps a key to the type(s) its value must have (``(int, float)``, ``dict``,
    ``type(None)``...); a key missing or of another type, a file that is not JSON or not a
    JSON object, are one line naming the file (``ValueError``), never a traceback further on.
    """
    import json

    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read this {what} ({exc.strerror or exc}); "
                         f"{advice}") from None
    except (ValueError, UnicodeDecodeError):
        raise ValueError(f"{path} is not valid JSON (a damaged {what}); {advice}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} holds {_kind(data)}, not the JSON object a {what} holds; "
                         f"{advice}")
    for key, types in (fields or {}).items():
        types = types if isinstance(types, tuple) else (types,)
        if key not in data:
            raise ValueError(f"{path} has no {key!r} field (a damaged {what}); {advice}")
        value = data[key]
        ok = isinstance(value, types) and not (isinstance(value, bool) and bool not in types)
        if not ok:
            want = " or ".join(_JSON_TYPES.get(t, "null" if t is type(None) else t.__name__)
                               for t in types)
            raise ValueError(f"{path}: {key!r} holds {_kind(value)}, not {want} (a damaged "
                             f"{what}); {advice}")
    return data


def _kind(value) -> str:
    if value is None:
        return "null"
    for t, name in _JSON_TYPES.items():
        if type(value) is t:
            return name
    return type(value).__name__


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


def _nothing_kept(path: Path) -> bool:
    """Only the lock file and an empty ``figures/`` in ``path``."""
    from sern_jax.infra import io

    left = [c.name for c in path.iterdir() if c.name not in (io.LOCK_FILE, "figures")]
    figures = path / "figures"
    return not left and not (figures.is_dir() and any(figures.iterdir()))


@contextlib.contextmanager
def locked_run_dir(path: str | os.PathLike, command: str | None = None) -> Iterator[Path]:
    """``io.run_lock(path)``, which creates and locks the directory in one step; if that call
    created it and the block fails before anything but the lock file (and an empty
    ``figures/``) was written, the directory is removed again, under the lock. A directory
    another process created or holds is never removed."""
    from sern_jax.infra import io

    with io.run_lock(path, command=command, remove_unused=_nothing_kept) as run_dir:
        yield run_dir
