"""Host-side I/O: run directories, atomic writes, metadata, checkpoints.

Never imported by jitted code. Every write goes to a temporary file in the same directory
followed by ``os.replace``, so an interrupted run never leaves a half-written result file.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import platform
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "peak_rss_mb",
    "make_run_dir",
    "save_json",
    "save_text",
    "save_bytes",
    "load_json",
    "save_npz",
    "load_npz",
    "run_metadata",
    "to_jsonable",
]


def make_run_dir(root: str | os.PathLike, name: str, *, exist_ok: bool = True) -> Path:
    """Creates (or reuses) ``root/name`` with a ``figures/`` subfolder and returns it."""
    path = Path(root) / name
    path.mkdir(parents=True, exist_ok=exist_ok)
    (path / "figures").mkdir(exist_ok=True)
    return path


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


def save_npz(path: str | os.PathLike, **arrays: Any) -> None:
    """Writes arrays to a compressed ``.npz``, atomically."""
    import io as _io

    buf = _io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    _atomic_write_bytes(Path(path), buf.getvalue())


def load_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


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
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        )
        if out.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here, capture_output=True, text=True, timeout=5,
        ).stdout.strip()
        return out.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


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
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "versions": versions,
        "python": platform.python_version(),
        "git_commit": _git_commit(),
        "host": {
            "machine": platform.machine(),
            "processor": platform.processor() or None,
            "cpu_count": os.cpu_count(),
            "system": platform.system(),
        },
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
