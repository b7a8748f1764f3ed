"""Host-side I/O: run directories, atomic writes, verified npz files, run locks, metadata.

Never imported by jitted code. Every write goes to a temporary file in the same directory
followed by ``os.replace``, so an interrupted run never leaves a half-written result file.

Verified npz files. :func:`save_npz` stores, inside the archive, a SHA-256 of every array
(name, dtype, shape, bytes) under :data:`DIGEST_KEY`; the zip format adds a CRC-32 and the
length of every member and a central directory at the end. :func:`load_npz` reads every member
back and checks all three, so a truncated, empty, overwritten or random file raises
:class:`DamagedFileError` (a ``ValueError`` whose message is one line: the file, what is wrong,
what to do) instead of ``BadZipFile`` / ``EOFError`` / ``zlib.error`` from deep inside numpy.
Files written before the digest existed load as before (zip CRC and lengths still checked).
Deterministic units (D0 shards, regret seed chunks) use :func:`load_npz_unit` /
:func:`npz_unit_done`: a damaged unit is moved aside to ``<name>.damaged``, reported as
``damaged -> recomputing`` and treated as missing, so the caller recomputes it.

Run locks. :func:`run_lock` holds an exclusive ``flock`` on ``<run dir>/.sern.lock`` while a
command writes that directory. A second process gets :class:`RunLockedError` at once (one line:
the directory, the holder's pid, host, start time and command). The kernel drops a ``flock``
when its process dies (``kill -9`` included), so a killed run leaves no stale lock: the file
stays, unlocked, and the next run takes it. On one machine this is exact. On a cluster: Linux
maps ``flock`` on NFS to a POSIX lock held by the NFS server (NFSv4 releases it when the dead
client's lock times out, about 90 s); some parallel filesystems (Lustre without ``-o flock``) refuse
it, and then :func:`run_lock` raises ``RunLockedError`` naming the filesystem error rather than
running unlocked. With Ray, the driver process holds the run directory's lock and the workers
write only deterministic unit files (atomically, by ``os.replace``): two workers computing the
same unit write the same bytes, so units need no lock of their own.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import hashlib
import json
import os
import platform
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from sern_jax.infra import hosts

__all__ = [
    "DIGEST_KEY",
    "LOCK_FILE",
    "refuse_if_locked",
    "DamagedFileError",
    "RunLockedError",
    "check_run_dir",
    "fmt_bytes",
    "fmt_time",
    "load_json",
    "load_npz",
    "load_npz_unit",
    "machine",
    "make_run_dir",
    "npz_unit_done",
    "peak_rss_mb",
    "run_lock",
    "run_metadata",
    "save_bytes",
    "save_json",
    "save_npz",
    "save_text",
    "to_jsonable",
    "verify_npz",
]


def make_run_dir(root: str | os.PathLike, name: str, *, exist_ok: bool = True) -> Path:
    """Creates (or reuses) ``root/name`` with a ``figures/`` subfolder and returns it."""
    path = Path(root) / name
    path.mkdir(parents=True, exist_ok=exist_ok)
    (path / "figures").mkdir(exist_ok=True)
    return path


def check_run_dir(run_dir: str | os.PathLike, fingerprint: str, *,
                  flag: str = "--out", what: str = "experiment",
                  checkpoint: str | None = None, advice: str | None = None) -> None:
    """Refuses a run directory made with other settings, before anything is computed.

    A run directory may be absent (a new run), or a directory without ``config.json`` (a run
    that saved nothing yet), or one whose ``config.json`` holds the same ``fingerprint`` (the
    same experiment, which then resumes). Anything else is refused, so one directory never
    mixes results of two settings. Reads only; writes nothing.

    Runs that save a checkpoint before their ``config.json`` (``sern grasp learn`` writes
    ``config.json`` when it finishes) name it: its ``"fingerprint"`` array must match too,
    and it is checked first, verified (:func:`load_npz`), so a run stopped before its end is
    never resumed by other settings either.

    Args:
      run_dir: the run directory the command was given.
      fingerprint: the experiment's fingerprint (``<Experiment>.fingerprint()``), compared
        with ``config.json``'s ``"fingerprint"`` field.
      flag: the command-line flag that named ``run_dir``, quoted in the messages.
      what: what the directory holds, in the message (``"learning run"``).
      checkpoint: a verified npz file in ``run_dir`` (e.g. ``"checkpoint.npz"``) whose
        ``"fingerprint"`` member must equal ``fingerprint`` when it exists; None: none.
      advice: the end of the message when that checkpoint is damaged (:func:`load_npz`);
        default: delete it, or choose another ``flag``.

    Raises:
      ValueError: one line naming ``flag`` or the directory: ``run_dir`` exists and is not a
        directory; the checkpoint is damaged (:class:`DamagedFileError`); its ``config.json``
        is unreadable (or not a JSON object); or either holds a different fingerprint.
    """
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"{flag} {run_dir} exists and is not a directory")

    def refuse(old, kind=what) -> None:
        raise ValueError(f"{run_dir} holds a different {kind} (fingerprint {old} != "
                         f"{fingerprint}); choose another {flag} or delete it")

    if checkpoint is not None and (run_dir / checkpoint).exists():
        saved = load_npz(run_dir / checkpoint,
                         advice=advice or f"delete it (or choose another {flag}) and rerun")
        old = saved.get("fingerprint")
        old = None if old is None else str(old)
        if old != fingerprint:
            refuse(old)
    cfg_path = run_dir / "config.json"
    if not cfg_path.exists():
        return
    try:
        old = load_json(cfg_path)
    except (OSError, ValueError):
        old = None
    if not isinstance(old, dict):  # commands turn ValueError into exit 2: not a TypeError
        raise ValueError(f"{cfg_path} is unreadable; choose another {flag} or delete it")  # noqa: TRY004
    if old.get("fingerprint") != fingerprint:
        # without the checkpoint this kind of run saves, the directory may be any command's
        # run (e.g. a finished `sern regret`): do not call it a different ``what``
        known = checkpoint is None or (run_dir / checkpoint).exists()
        refuse(old.get("fingerprint"), what if known else "run")


def _umask() -> int:
    """The process umask: read from /proc on Linux (no race with other threads), else set and
    restored at once."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        # mkstemp creates the file 0600; give it the mode open() would (0666 less the umask)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def to_jsonable(obj: Any) -> Any:
    """Converts dataclasses, NamedTuples, numpy/jax arrays and scalars to JSON types."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {k: to_jsonable(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, tuple) and hasattr(obj, "_asdict"):
        return {k: to_jsonable(v) for k, v in obj._asdict().items()}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "__array__") and not isinstance(obj, (str, bytes)):
        arr = np.asarray(obj)
        if arr.ndim == 0:
            return to_jsonable(arr.item())
        return arr.tolist()
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    return obj


def save_text(path: str | os.PathLike, text: str) -> None:
    """Writes ``text`` (UTF-8), atomically."""
    _atomic_write_bytes(Path(path), text.encode())


def save_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Writes ``data``, atomically."""
    _atomic_write_bytes(Path(path), data)


def save_json(path: str | os.PathLike, obj: Any) -> None:
    """Writes ``obj`` as indented JSON, atomically."""
    text = json.dumps(to_jsonable(obj), indent=2, sort_keys=False)
    _atomic_write_bytes(Path(path), (text + "\n").encode())


def load_json(path: str | os.PathLike) -> Any:
    with open(path) as f:
        return json.load(f)


DIGEST_KEY = "__sern_sha256__"  # the archive member holding the arrays' SHA-256
DAMAGED_SUFFIX = ".damaged"


class DamagedFileError(ValueError):
    """A file that exists but does not read back as it was written (truncated, empty, random
    bytes, another format, or contents that do not match their recorded SHA-256).

    ``str(error)`` is one line: ``<path> is damaged (<reason>); <advice>``.
    """

    def __init__(self, path: str | os.PathLike, reason: str, advice: str):
        self.path = Path(path)
        self.reason = reason
        self.advice = advice
        super().__init__(f"{path} is damaged ({reason}); {advice}")


def _digest(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over every array's name, dtype, shape and bytes (names in sorted order)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(memoryview(a.reshape(-1).view(np.uint8)) if a.size else b"")
    return h.hexdigest()


def save_npz(path: str | os.PathLike, **arrays: Any) -> None:
    """Writes arrays to a compressed ``.npz``, atomically, with their SHA-256 inside
    (:data:`DIGEST_KEY`; :func:`load_npz` checks it and does not return it)."""
    import io as _io

    if DIGEST_KEY in arrays:
        raise ValueError(f"{DIGEST_KEY} is reserved for the file's checksum")
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    buf = _io.BytesIO()
    np.savez_compressed(buf, **arrays, **{DIGEST_KEY: np.asarray(_digest(arrays))})
    _atomic_write_bytes(Path(path), buf.getvalue())


def _one_line(text: str, limit: int = 120) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _read_npz(path: Path) -> tuple[dict[str, np.ndarray] | None, str | None]:
    """(arrays, None) for an intact file, (None, reason) for a damaged one. A missing or
    unreadable (permission) file raises ``OSError``."""
    size = os.stat(path).st_size  # FileNotFoundError / PermissionError propagate
    if size == 0:
        return None, "empty file, 0 bytes"
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
        if magic != b"PK\x03\x04":
            return None, f"not an npz archive ({size:,} bytes that do not start as a zip file)"
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}  # reads every member: CRC and length
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, zlib.error, struct.error,
            ValueError, KeyError, IndexError, UnicodeDecodeError, NotImplementedError) as exc:
        reason = _one_line(f"{type(exc).__name__}: {exc}") if str(exc) else type(exc).__name__
        if isinstance(exc, zipfile.BadZipFile) and "not a zip file" in str(exc):
            reason = f"truncated or not an npz archive: {size:,} bytes, no zip directory"
        return None, reason
    except OSError as exc:  # an I/O error inside the archive (not a missing file)
        if isinstance(exc, (FileNotFoundError, PermissionError)):
            raise
        return None, _one_line(f"{type(exc).__name__}: {exc}")
    recorded = arrays.pop(DIGEST_KEY, None)
    if recorded is not None and str(recorded) != _digest(arrays):
        return None, "contents do not match their recorded SHA-256"
    return arrays, None


def load_npz(path: str | os.PathLike, *, advice: str | None = None) -> dict[str, np.ndarray]:
    """Reads every array of an ``.npz`` written by :func:`save_npz`, verified.

    Args:
      path: the file.
      advice: what the user should do if the file is damaged (the end of the error message);
        default ``"delete it (or restore a copy) and rerun"``.

    Returns:
      name -> array (without the checksum member).

    Raises:
      FileNotFoundError: no such file (as ``open`` would).
      DamagedFileError: truncated, empty, random bytes, another format, a member whose CRC or
        length is wrong, or contents that do not match their SHA-256.
    """
    arrays, reason = _read_npz(Path(path))
    if arrays is None:
        raise DamagedFileError(path, reason, advice or "delete it (or restore a copy) and rerun")
    return arrays


def verify_npz(path: str | os.PathLike) -> str | None:
    """None when ``path`` reads back intact; otherwise why it is damaged (one line).

    Reads the whole file (every member is decompressed and checked). A missing file raises
    ``FileNotFoundError``.
    """
    return _read_npz(Path(path))[1]


def _set_aside(path: Path, reason: str, log: Callable[[str], None] | None) -> None:
    aside = path.with_name(path.name + DAMAGED_SUFFIX)
    os.replace(path, aside)
    if log is not None:
        log(f"{path}: damaged ({reason}) -> recomputing (the damaged file is kept as "
            f"{aside.name})")


def load_npz_unit(path: str | os.PathLike,
                  log: Callable[[str], None] | None = print) -> dict[str, np.ndarray] | None:
    """Loads a deterministic unit of work (a D0 shard, a regret seed chunk), or None.

    None when the file is missing, or damaged: a damaged file is renamed to
    ``<name>.damaged`` (kept for inspection, never read again), ``log`` gets one line
    ``<path>: damaged (<reason>) -> recomputing ...``, and the caller recomputes the unit as
    if it had never been written. Only for files whose contents a rerun reproduces exactly.
    """
    path = Path(path)
    try:
        arrays, reason = _read_npz(path)
    except FileNotFoundError:
        return None
    if arrays is None:
        _set_aside(path, reason, log)
    return arrays


def npz_unit_done(path: str | os.PathLike, log: Callable[[str], None] | None = print) -> bool:
    """True when the unit file exists and reads back intact; False when it is missing or was
    damaged (then set aside and reported as by :func:`load_npz_unit`)."""
    return load_npz_unit(path, log) is not None


# ----------------------------------------------------------------------------- run locks

LOCK_FILE = ".sern.lock"
_HELD: dict[str, int] = {}  # run directories this process holds -> nesting depth


class RunLockedError(ValueError):
    """Another live process holds the run directory's lock (or the filesystem refuses locks).

    ``str(error)`` is one line naming the directory, the holder and what to do.
    """


def _holder_text(lock_path: Path) -> str:
    try:
        info = json.loads(lock_path.read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    if not info:
        return "another process"
    return (f"pid {info.get('pid')} on {info.get('host')} since {info.get('started')}: "
            f"{_one_line(info.get('command', '?'), 80)}")


@contextlib.contextmanager
def run_lock(run_dir: str | os.PathLike, *, command: str | None = None,
             remove_unused: Callable[[Path], bool] | None = None) -> Iterator[Path]:
    """Holds the exclusive lock of a run directory while the block runs.

    Creates ``run_dir`` (and parents) if needed and takes a non-blocking ``flock`` on
    ``run_dir/.sern.lock`` in one step, then writes the holder (pid, host, UTC start time,
    command line) into it. Released on exit, and by the kernel if the process dies (no stale
    locks). After the ``flock`` the lock file must still be the one at its path (same device
    and inode): a directory removed by its holder between this process's ``open`` and its
    ``flock`` is created again and locked anew, so two processes never hold two locks of one
    path.

    Call it after validating the inputs (it creates the directory); re-read anything another
    process could have written (config.json, checkpoints) after entering, under the lock.
    Re-entrant within a process: a command that holds the lock may call a library function
    that takes it again (the inner call passes through).

    Args:
      run_dir: the run directory.
      command: shown to a second process (default: this process's command line).
      remove_unused: when this call created ``run_dir`` (its ``mkdir`` made it) and the block
        raises, ``remove_unused(run_dir)`` is asked, still under the lock, whether nothing
        worth keeping was written; if so the directory is removed before the lock is
        released. A process that did not create the directory, or never held its lock,
        never removes it.

    Yields:
      ``run_dir`` as a Path.

    Raises:
      RunLockedError: a live process holds the lock, or the filesystem does not support locks.
    """
    import fcntl

    run_dir = Path(run_dir)
    key = os.path.realpath(run_dir)
    if _HELD.get(key):
        _HELD[key] += 1
        try:
            yield run_dir
        finally:
            _HELD[key] -= 1
        return
    lock_path = run_dir / LOCK_FILE
    for _ in range(100):  # a lost race with a holder that removed the directory: retry
        created = False
        try:
            run_dir.mkdir(parents=True)
            created = True
        except FileExistsError:
            if not run_dir.is_dir():
                raise
        try:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW,
                         0o666)
        except FileNotFoundError:  # removed between the mkdir and the open
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RunLockedError(
                f"{run_dir} is in use by {_holder_text(lock_path)}; wait for that run to "
                "finish (or stop it), then rerun; a killed run's lock is released by itself"
            ) from None
        except OSError as exc:
            os.close(fd)
            raise RunLockedError(
                f"{run_dir}: this filesystem refuses file locks ({exc.strerror or exc}); "
                "use a run directory on a local or lock-capable filesystem") from None
        held = os.fstat(fd)
        try:
            now = os.stat(lock_path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        if now is not None and (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
            break
        os.close(fd)  # we locked a file its holder had removed: start again
    else:
        raise RunLockedError(f"{run_dir} keeps being removed while this run tries to lock it; "
                             "rerun when no other run uses it")
    try:
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "started": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                "command": command if command is not None else " ".join(
                    [Path(sys.argv[0]).name, *sys.argv[1:]])}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        _HELD[key] = 1
        try:
            yield run_dir
        except BaseException:
            if created and remove_unused is not None:
                with contextlib.suppress(OSError):
                    if remove_unused(run_dir):
                        # removed while the lock is held: a process that opened the lock
                        # file meanwhile finds it gone after its flock and starts again
                        shutil.rmtree(run_dir, ignore_errors=True)
            raise
        finally:
            _HELD.pop(key, None)
            # the file stays (unlinking it would let two processes lock two inodes); emptied
            # so that it names no holder while unlocked
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
    finally:
        os.close(fd)  # releases the flock


def refuse_if_locked(run_dir: str | os.PathLike | None) -> None:
    """``RunLockedError`` (one line naming the holder) when a live process holds
    ``run_dir``'s lock now: the cheap early check a command makes before its heavy imports
    and compiles (the lock itself is still taken later, by :func:`run_lock`). Writes
    nothing: the lock file is opened read-only and only if it exists."""
    import fcntl

    if run_dir is None:
        return
    lock_path = Path(run_dir) / LOCK_FILE
    if os.path.realpath(Path(run_dir)) in _HELD:
        return
    try:
        fd = os.open(lock_path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return  # no lock file (or none readable): nobody to wait for
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        raise RunLockedError(
            f"{run_dir} is in use by {_holder_text(lock_path)}; wait for that run to finish "
            "(or stop it), then rerun; a killed run's lock is released by itself") from None
    except OSError:
        pass  # a filesystem without locks: run_lock reports it
    finally:
        os.close(fd)


def peak_rss_mb() -> float:
    """This process's peak resident memory in MiB.

    Reads ``VmHWM`` from ``/proc/self/status`` on Linux: ``getrusage``'s ``ru_maxrss`` would
    carry a parent's larger peak over ``fork``/``exec`` (a benchmark started from a big process
    would report the parent's memory). Elsewhere falls back to ``ru_maxrss`` (bytes on macOS,
    KiB on other systems).
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def _git_commit() -> str | None:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5,
            check=False,
        )
        if out.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here, capture_output=True, text=True, timeout=5, check=False,
        ).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what ``platform`` knows."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine(*, devices: bool = False) -> dict[str, Any]:
    """The machine a figure was measured on: the one machine-description helper.

    Keys: ``cpu`` (model name), ``processor``, ``machine`` (architecture), ``cpu_count``,
    ``cores_usable`` (this process's CPU affinity), ``system``, ``platform``, ``python``,
    ``load_average_1m``; with ``devices=True`` also
    ``jax_backend`` and ``jax_devices`` (imports jax). Used by :func:`run_metadata` (its
    ``host``) and by the benchmarks' ``machine`` field.
    """
    info: dict[str, Any] = {
        "cpu": _cpu_model(),
        "processor": platform.processor() or platform.machine(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "cores_usable": hosts.usable_cores(),
        "system": platform.system(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "load_average_1m": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
    }
    if devices:
        import jax

        info["jax_backend"] = jax.default_backend()
        info["jax_devices"] = [str(d) for d in jax.devices()]
    return info


def run_metadata(**extra: Any) -> dict[str, Any]:
    """Versions, git commit, JAX flags and devices, host, time: what a run was made with."""
    import importlib.metadata as md

    versions = {}
    for pkg in ("sern_jax", "jax", "jaxlib", "numpy", "optax", "flax", "mujoco", "mujoco-mjx"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = None
    meta: dict[str, Any] = {
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "versions": versions,
        "python": platform.python_version(),
        "git_commit": _git_commit(),
        "host": machine(),
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "JAX_PLATFORMS", "MUJOCO_GL")},
    }
    try:
        import jax

        meta["jax"] = {
            "backend": jax.default_backend(),
            "devices": [str(d) for d in jax.devices()],
            "enable_x64": bool(jax.config.jax_enable_x64),
            "threefry_partitionable": bool(jax.config.jax_threefry_partitionable),
        }
    except Exception as exc:  # noqa: BLE001 - metadata must never kill a run
        meta["jax"] = {"error": repr(exc)}
    meta.update(extra)
    return meta


def fmt_bytes(n: float) -> str:
    """A byte count for a message: ``fmt_bytes(3 * 2**30) == '3 GiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"


def fmt_time(s: float) -> str:
    """A duration in seconds for a message: s, min, h or days."""
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 172800:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.3g} days"
