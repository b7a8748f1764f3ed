"""Scale-out on Ray: units of work as Ray tasks, each writing its files into the run directory.

The run directories already resume by unit of work: a regret seed chunk, a D0 shard, a grid
cell, a grasp-learning object (all its learner copies: ``sern_jax.grasp.online.learn_units``). This module runs such units as Ray tasks instead of in the calling process, so that one
command spreads over every core of a machine or over a cluster:

* a :class:`Unit` is ``fn(*args)``: a module-level function that computes one unit and
  writes its result file(s) atomically (``io.save_npz`` / ``io.save_json``: temporary file,
  ``fsync``, ``os.replace``) at the same path, with the same bytes, as the single-process
  run. The caller lists only the units whose files are missing (or damaged: ``io``
  verifies them), so an interrupted or partly failed Ray run resumes with the same command,
  and a run equals the single-process one bit for bit because both call the same ``fn``;
* :func:`run_units` submits every unit as a task (``num_cpus``, ``num_gpus``, Ray's
  ``max_retries`` for a worker that dies mid-task, e.g. killed or out of memory), waits for
  them, and on the first task that fails for good (an exception in ``fn``, or a worker that
  died ``max_retries + 1`` times) cancels the others and raises :class:`UnitFailedError`:
  one line naming the unit and the error. Finished units are on disk and are kept.
* JAX in workers: every task gets environment variables set before its worker imports jax:
  ``JAX_COMPILATION_CACHE_DIR`` (a persistent compilation cache, by default this user's
  ``~/.cache/sern_jax/jax``, created private: never inside a run directory, whose files may
  come from elsewhere, so that resuming a run directory never loads compiled code it holds),
  the CPU threads per task (``XLA_FLAGS`` intra-op threads, ``OMP_NUM_THREADS``, and
  ``SERN_CPU_THREADS``, which :func:`sern_jax.engine.drive.host_workers` honours; a CPU task
  also pins its worker process to as many cores of its own: :func:`_pin_cores`), and
  ``JAX_PLATFORMS=cpu`` for tasks that ask for no GPU (so eight CPU tasks on a GPU machine
  do not each grab the GPU); tasks with ``gpus_per_task > 0`` ask Ray for ``num_gpus``.

The driver (the process that runs the command) holds the run directory's lock
(``io.run_lock``); workers write only deterministic unit files, so two workers that compute
the same unit (a retry after a lost reply) write the same bytes.

Ray stays optional: importing this module does not import ray; :func:`require_ray` does, and
turns a missing installation into one line naming ``--ray`` and the ``[ray]`` extra.

``--ray ADDRESS`` is joined before anything is written: :func:`from_args` opens a TCP
connection to the address with a bound of :data:`CONNECT_TIMEOUT_S` seconds and refuses an
address nobody answers at in one line naming ``--ray``; then :func:`join` gives Ray
:data:`JOIN_TIMEOUT_S` seconds to join the cluster there, and a watchdog ends the process in
one line when it does not (or on SIGTERM, which Ray's connection loop would hold up). The
local Ray that ``--ray`` starts keeps loopback (``127.0.0.1``) as its node address
(:func:`_loopback_node`), so every server it starts (GCS, raylet, object manager, workers,
agents) listens on loopback only. Ray's own log lines stay out of the terminal (errors
only).

Security: Ray 2.60 turns token authentication on by default. Keep it on, and never expose a
head node's ports: anyone who reaches an open Ray head can run code on every node
(``docs/CLUSTER.md``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

__all__ = [
    "LOCAL",
    "EXTRA",
    "RayConfig",
    "Unit",
    "UnitFailedError",
    "add_arguments",
    "check_backend",
    "from_args",
    "join",
    "require_ray",
    "worker_env",
    "run_units",
]

LOCAL = "local"  # --ray without an address: start a Ray on this machine
EXTRA = "pip install -e '.[ray]'"
CONNECT_TIMEOUT_S = 10.0  # --ray ADDRESS: seconds the address has to answer
JOIN_TIMEOUT_S = 30.0  # --ray ADDRESS: seconds Ray then has to join the cluster there
LOOPBACK = "127.0.0.1"  # the local Ray's node address


@dataclasses.dataclass(frozen=True)
class RayConfig:
    """How a command runs its units on Ray (``--ray`` and its companion flags).

    Attributes:
      address: ``"local"`` starts a Ray on this machine for the run (stopped after it);
        ``"auto"`` joins the running cluster (``ray start`` on this machine); anything else
        is a cluster address (``host:port`` or ``ray://host:port``).
      workers: local Ray only: concurrent tasks (the local Ray gets ``workers *
        cpus_per_task`` CPUs); None: every core.
      cpus_per_task: CPUs Ray reserves per task, and the CPU threads the task's JAX uses.
      gpus_per_task: GPUs Ray reserves per task (0: the task runs JAX on the CPU).
      max_retries: how often Ray reruns a task whose worker died (killed, out of memory).
      spread: Ray's SPREAD scheduling (tasks spread over nodes rather than packed).
      cache_dir: JAX's persistent compilation cache; None: this user's private
        ``~/.cache/sern_jax/jax`` (:func:`default_cache_dir`), never a run directory.
      pin_cores: CPU tasks pin their worker process to ``cpus_per_task`` cores of their own
        (claimed per node by file locks), so that JAX's and XLA's threads of one task do not
        spread over the cores other tasks run on.
    """

    address: str = LOCAL
    workers: int | None = None
    cpus_per_task: int = 1
    gpus_per_task: float = 0.0
    max_retries: int = 3
    spread: bool = False
    cache_dir: str | None = None
    pin_cores: bool = True

    def __post_init__(self):
        if not isinstance(self.address, str) or not self.address.strip():
            raise ValueError(f"--ray: the address must be 'auto' or host:port, got "
                             f"{self.address!r}")
        if self.workers is not None and (isinstance(self.workers, bool) or self.workers < 1):
            raise ValueError(f"--ray-workers must be an integer >= 1, got {self.workers!r}")
        if self.workers is not None and self.address != LOCAL:
            raise ValueError("--ray-workers sizes the local Ray that --ray without an address "
                             "starts; a cluster's size is set where it was started")
        if isinstance(self.cpus_per_task, bool) or self.cpus_per_task < 1:
            raise ValueError(f"--ray-cpus must be an integer >= 1, got {self.cpus_per_task!r}")
        if not 0.0 <= float(self.gpus_per_task) <= 64 or self.gpus_per_task != \
                self.gpus_per_task:
            raise ValueError(f"--ray-gpus must be a number in [0, 64], got "
                             f"{self.gpus_per_task!r}")
        if isinstance(self.max_retries, bool) or not 0 <= self.max_retries <= 1000:
            raise ValueError(f"--ray-retries must be an integer in [0, 1000], got "
                             f"{self.max_retries!r}")


class Unit(NamedTuple):
    """One unit of work: ``fn(*args)`` computes it and writes its file(s) atomically.

    ``fn`` must be a module-level function (Ray ships it by reference), importable on every
    node; ``name`` is what messages call the unit (its file name).
    """

    name: str
    fn: Callable[..., Any]
    args: tuple


class UnitFailedError(RuntimeError):
    """A unit failed for good on Ray; ``str(error)`` is one line naming the unit and error."""

    def __init__(self, unit: str, error: str):
        self.unit = unit
        self.error = error
        super().__init__(f"--ray: unit {unit} failed: {error}; every finished unit is kept, "
                         "rerun the same command to resume")


def add_arguments(parser, *, gpus_default: float = 0.0) -> None:
    """Adds ``--ray [ADDRESS]`` and its companions to an argparse parser."""
    from sern_jax.infra import validate

    parser.add_argument(
        "--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
        type=validate.ray_address,
        help="run the units of work as Ray tasks (needs the [ray] extra: "
             f"{EXTRA}); no ADDRESS starts a local Ray (node address 127.0.0.1), 'auto' "
             "joins the cluster started on this machine with `ray start`, host:port another "
             "one; an "
             f"address that does not answer within {CONNECT_TIMEOUT_S:g} s, or where Ray "
             f"does not join a cluster within {JOIN_TIMEOUT_S:g} s more, is refused before "
             "anything is written; same run directory and results as without --ray")
    parser.add_argument("--ray-workers", type=validate.int_in(1, 1_000_000), default=None,
                        metavar="N",
                        help="with --ray and no address: concurrent tasks of the local Ray "
                             "(default: every core)")
    parser.add_argument("--ray-cpus", type=validate.int_in(1, 4096), default=1, metavar="N",
                        help="with --ray: CPUs (and JAX CPU threads) per task")
    parser.add_argument("--ray-gpus", type=validate.float_in(0.0, 64.0), default=gpus_default,
                        metavar="G",
                        help="with --ray: GPUs per task (0: tasks compute on the CPU)")
    parser.add_argument("--ray-retries", type=validate.int_in(0, 1000), default=3, metavar="N",
                        help="with --ray: reruns of a task whose worker died")


def from_args(args) -> RayConfig | None:
    """The :class:`RayConfig` of parsed arguments (None without ``--ray``), validated.

    Raises ValueError (one line naming the flag) for a bad value, a companion flag given
    without ``--ray``, or ``--ray`` when ray is not installed; imports ray only to check that.
    ``--ray ADDRESS`` joins the cluster here, before the command writes anything: the address
    must answer within :data:`CONNECT_TIMEOUT_S` seconds (:func:`probe`), and Ray must join
    it within :data:`JOIN_TIMEOUT_S` more (:func:`join`, which otherwise ends the process in
    one line).
    """
    address = getattr(args, "ray", None)
    if address is None:
        for flag, name, default in (("--ray-workers", "ray_workers", None),
                                    ("--ray-cpus", "ray_cpus", 1),
                                    ("--ray-gpus", "ray_gpus", 0.0),
                                    ("--ray-retries", "ray_retries", 3)):
            if getattr(args, name, default) != default:
                raise ValueError(f"{flag} applies to --ray runs; add --ray")
        return None
    config = RayConfig(address=address, workers=getattr(args, "ray_workers", None),
                       cpus_per_task=getattr(args, "ray_cpus", 1),
                       gpus_per_task=float(getattr(args, "ray_gpus", 0.0)),
                       max_retries=getattr(args, "ray_retries", 3))
    ray = require_ray()
    if config.address != LOCAL and not ray.is_initialized():
        probe(ray, config.address)
        join(ray, config.address)  # before anything is written: bounded, or one line
    return config


def probe(ray, address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Refuses (``ValueError``, one line naming ``--ray``) an address where nothing answers
    within ``timeout`` seconds: a TCP connection to the cluster's address (``auto``: the one
    ``ray start`` recorded on this machine), so that a typo fails in seconds, before anything
    is written, instead of Ray retrying for minutes."""
    import socket

    target = address
    if address == "auto":
        try:
            from ray._private import services

            with _quiet_ray_logs():
                target = services.canonicalize_bootstrap_address(address)
        except Exception as exc:  # noqa: BLE001 - any failure to find it is one line
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise ValueError(f"--ray {address}: cannot join a Ray cluster there "
                             f"({_one_line(first, 160)}); start one with `ray start --head` "
                             "or give its host:port") from None
        if not target:
            raise ValueError(f"--ray {address}: cannot join a Ray cluster there (none is "
                             "running on this machine); start one with `ray start --head`")
    host, _, port = target.removeprefix("ray://").rpartition(":")
    host = host.strip("[]")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except (OSError, ValueError) as exc:
        reason = ("no answer" if isinstance(exc, TimeoutError)
                  else getattr(exc, "strerror", None) or str(exc) or type(exc).__name__)
        raise ValueError(f"--ray {address}: cannot join a Ray cluster there ({reason} within "
                         f"{timeout:g} s); check the host and port, that the cluster runs "
                         "and that this machine may reach it") from None


@contextlib.contextmanager
def _quiet_ray_logs():
    """Ray's loggers at ERROR while the block runs (its warnings would add lines to a
    one-line error)."""
    loggers = [logging.getLogger(name) for name in ("ray", "ray._private")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def check_backend(backend: str, config: RayConfig | None) -> None:
    """Refuses ``--backend mjx`` on Ray without ``--ray-gpus``: its tasks would run MJX on
    their CPUs (``JAX_PLATFORMS=cpu``), another float program than a GPU run, and the run
    fingerprint does not name the platform, so a GPU-started run directory resumed that way
    would mix the two. One line naming the flag (ValueError)."""
    if config is not None and backend == "mjx" and not config.gpus_per_task > 0:
        raise ValueError("--backend mjx with --ray needs --ray-gpus G > 0 (without it the "
                         "tasks run MJX on the CPU, another float program than a GPU run of "
                         "the same run directory); or use --backend native")


def require_ray():
    """Imports ray, or raises ValueError: one line naming ``--ray`` and the extra."""
    try:
        import ray
    except ImportError:
        raise ValueError(f"--ray needs Ray, which is not installed: {EXTRA} (or pip install "
                         "'sern_jax[ray]')") from None
    return ray


def _xla_flags(existing: str, threads: int) -> str:
    """``existing`` without its thread flags, plus this task's."""
    keep = [f for f in existing.split() if not f.startswith(
        ("--xla_cpu_multi_thread_eigen", "intra_op_parallelism_threads"))]
    mine = (["--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1"]
            if threads == 1 else [f"intra_op_parallelism_threads={threads}"])
    return " ".join(keep + mine)


def worker_env(config: RayConfig, run_dir: str | os.PathLike) -> dict[str, str]:
    """Environment variables of every task (set before the worker imports jax)."""
    threads = int(config.cpus_per_task)
    cache = config.cache_dir or os.environ.get("JAX_COMPILATION_CACHE_DIR") or \
        default_cache_dir()
    run = Path(run_dir).resolve()
    if Path(cache).resolve() == run or run in Path(cache).resolve().parents:
        raise ValueError(f"--ray: the compilation cache {cache} lies inside the run directory "
                         f"{run_dir}; a run directory's files may come from elsewhere, so "
                         "keep the cache outside it (JAX_COMPILATION_CACHE_DIR)")
    env = {
        "SERN_CPU_THREADS": str(threads),
        "OMP_NUM_THREADS": str(threads),
        "OPENBLAS_NUM_THREADS": str(threads),
        "MKL_NUM_THREADS": str(threads),
        "XLA_FLAGS": _xla_flags(os.environ.get("XLA_FLAGS", ""), threads),
        "JAX_COMPILATION_CACHE_DIR": cache,
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "MUJOCO_GL": os.environ.get("MUJOCO_GL", "disable"),
    }
    if config.pin_cores and config.gpus_per_task == 0:
        env["SERN_PIN_CORES"] = "1"
    if config.gpus_per_task > 0:
        if config.gpus_per_task < 1:  # several tasks share a GPU: no preallocation
            env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
        if os.environ.get("JAX_PLATFORMS"):
            env["JAX_PLATFORMS"] = os.environ["JAX_PLATFORMS"]
    else:
        env["JAX_PLATFORMS"] = "cpu"
    return env


def default_cache_dir() -> str:
    """This user's JAX compilation cache for Ray tasks: ``$XDG_CACHE_HOME/sern_jax/jax`` (or
    ``~/.cache/sern_jax/jax``), outside every run directory; created with mode 0700."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = Path(base) / "sern_jax" / "jax"
    with contextlib.suppress(OSError):
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return str(path)


def private_dir(name: str) -> Path | None:
    """``<tmp>/<name>-<uid>``, this user's private directory: created with mode 0700, or
    accepted when it is a real directory (not a symlink) owned by this user and closed to
    others; None otherwise (a directory another user planted there is never used)."""
    import stat
    import tempfile

    path = Path(tempfile.gettempdir()) / f"{name}-{os.getuid()}"
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass  # checked below: ours, a real directory, closed to others
    except OSError:
        return None
    try:
        st = os.lstat(path)
    except OSError:
        return None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        return None
    return path


_PIN: dict[str, Any] = {}  # this worker process's claimed cores (lock fds, cores)


def _pin_cores(threads: int) -> list[int] | None:
    """Pins this worker process (every thread it has, and so the threads they start) to
    ``threads`` cores no other pinned worker of this user on this node holds, claimed by an
    exclusive ``flock`` on ``<tmp>/sern-ray-cores-<uid>/core-<i>`` (:func:`private_dir`:
    this user's, mode 0700, never a planted symlink; the files are opened with
    ``O_NOFOLLOW``) for the life of the process (the kernel releases it when it dies).
    Called before the unit's first JAX call, so XLA's CPU thread pool is sized to the
    claimed cores. None (unpinned) when too few cores are free."""
    if "cores" in _PIN:
        return _PIN["cores"]
    import fcntl

    lock_dir = private_dir("sern-ray-cores")
    fds, cores = [], []
    try:
        candidates = [] if lock_dir is None else sorted(os.sched_getaffinity(0))
    except OSError:  # no usable lock directory: run unpinned
        candidates = []
    for core in candidates:
        try:
            fd = os.open(lock_dir / f"core-{core}",
                         os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        fds.append(fd)
        cores.append(core)
        if len(cores) == threads:
            break
    if len(cores) < threads:
        for fd in fds:
            os.close(fd)
        _PIN["cores"] = None
        return None
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cores)
        except OSError:
            pass
    _PIN.update(cores=cores, fds=fds)
    return cores


def _call_unit(fn: Callable[..., Any], args: tuple) -> dict[str, Any]:
    """The Ray task: runs one unit; returns its wall and CPU seconds and where it ran."""
    cores = None
    if os.environ.get("SERN_PIN_CORES") == "1" and hasattr(os, "sched_setaffinity"):
        cores = _pin_cores(int(os.environ.get("SERN_CPU_THREADS", "1")))
    start, cpu = time.perf_counter(), os.times()
    fn(*args)
    end = os.times()
    import socket

    return {"seconds": time.perf_counter() - start,
            "cpu_seconds": (end.user - cpu.user) + (end.system - cpu.system),
            "threads": len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task")
            else None,
            "cores": cores, "pid": os.getpid(), "host": socket.gethostname()}


def _one_line(text: str, limit: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(exc: BaseException, max_retries: int) -> str:
    """One line for a failed task: the original exception where Ray wraps one."""
    ray = require_ray()
    cause = getattr(exc, "cause", None)
    if isinstance(exc, ray.exceptions.RayTaskError) and cause is not None:
        text = str(cause) or ""
        return _one_line(f"{type(cause).__name__}: {text}" if text else type(cause).__name__)
    if isinstance(exc, (ray.exceptions.WorkerCrashedError, ray.exceptions.OutOfMemoryError,
                        ray.exceptions.NodeDiedError)):
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        return _one_line(f"{type(exc).__name__}: its worker died {max_retries + 1} times "
                         f"(--ray-retries {max_retries}); {first}")
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return _one_line(f"{type(exc).__name__}: {first}" if first else type(exc).__name__)


def _init(ray, config: RayConfig) -> bool:
    """Connects to (or starts) Ray; True when this call started it (and must stop it)."""
    if ray.is_initialized():
        return False
    if config.address == LOCAL:
        cpus = None if config.workers is None else config.workers * config.cpus_per_task
        with _loopback_node(ray):
            ray.init(address="local", num_cpus=cpus, include_dashboard=False,
                     _node_ip_address=LOOPBACK, **_INIT_KWARGS)
    else:
        join(ray, config.address)
    return True


_INIT_KWARGS: dict[str, Any] = dict(logging_level=logging.ERROR, log_to_driver=True,
                                    configure_logging=True)


@contextlib.contextmanager
def _loopback_node(ray):
    """The local Ray's node address stays loopback while it starts, so every server it starts
    listens on 127.0.0.1 only.

    Ray 2.60 turns a loopback ``_node_ip_address`` into this machine's network address
    (``ray._private.services.resolve_ip_for_localhost``), and its servers then listen on
    every interface (its gRPC servers bind 127.0.0.1 only when the node address is
    127.0.0.1). It keeps loopback where ``ray._private.ray_constants.ENABLE_RAY_CLUSTER`` is
    off (its default on macOS and Windows): switched off here while ``ray.init`` starts the
    node, then restored. The processes it starts take the node address from their command
    line, so the switch matters only in this process."""
    constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
    if constants is None or not hasattr(constants, "ENABLE_RAY_CLUSTER"):
        yield
        return
    previous = constants.ENABLE_RAY_CLUSTER
    constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        constants.ENABLE_RAY_CLUSTER = previous


def join(ray, address: str, timeout: float = JOIN_TIMEOUT_S) -> None:
    """``ray.init(address=address)`` within ``timeout`` seconds, or the process ends in one
    line naming ``--ray``.

    Ray retries a cluster address that accepts connections but does not answer as Ray for
    minutes, inside C++ code that holds the main thread: no Python exception can stop it, and
    a SIGTERM waits for it. So a watchdog thread ends the process (``os._exit``) with one line
    on stderr: exit 2 after ``timeout`` seconds, 128 + N on SIGINT or SIGTERM (seen through
    ``signal.set_wakeup_fd``, which Python's C-level signal handler writes at once).
    :func:`from_args` calls it before anything is written, so ending the process leaves
    nothing behind. Ray's own lines (C++ warnings written to file descriptor 2) stay out of
    the terminal while it connects.

    Raises:
      ValueError: one line naming ``--ray`` when Ray refuses the address.
    """
    import select
    import signal
    import sys
    import threading

    stop = {int(signal.SIGINT), int(signal.SIGTERM)}
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    done, lock = threading.Event(), threading.Lock()
    sys.stderr.flush()
    terminal = os.dup(2)

    def end(line: str, code: int) -> None:
        with lock:
            if done.is_set():
                return
            os.write(terminal, (line + "\n").encode())
            os._exit(code)

    def watch() -> None:
        deadline = time.monotonic() + timeout
        while not done.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                end(f"--ray {address}: Ray did not join a cluster there within {timeout:g} "
                    "s; check the host and port (a Ray head's GCS port, 6379 by default), that "
                    "the cluster runs and that this machine may join it", 2)
                return
            if select.select([read_fd], [], [], left)[0]:
                with contextlib.suppress(OSError):
                    for signum in os.read(read_fd, 64):
                        if signum in stop:
                            end(f"--ray {address}: stopped by {signal.Signals(signum).name} "
                                "while joining the Ray cluster", 128 + signum)

    def ignore(signum, frame):  # the watchdog ends the process (set_wakeup_fd)
        pass

    main = threading.current_thread() is threading.main_thread()
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False) if main else None
    previous_term = signal.signal(signal.SIGTERM, ignore) if main else None
    quiet = os.open(os.devnull, os.O_WRONLY)
    os.dup2(quiet, 2)
    os.close(quiet)
    watchdog = threading.Thread(target=watch, name="sern-ray-join", daemon=True)
    watchdog.start()
    try:
        ray.init(address=address, **_INIT_KWARGS)
    except (ConnectionError, RuntimeError, ValueError) as exc:  # no cluster there
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"--ray {address}: cannot join a Ray cluster there "
                         f"({_one_line(first, 160)})") from None
    finally:
        with lock:
            done.set()
        with contextlib.suppress(OSError):
            os.write(write_fd, b"\0")  # wakes the watchdog
        watchdog.join()
        sys.stderr.flush()
        os.dup2(terminal, 2)
        os.close(terminal)
        if main:
            signal.set_wakeup_fd(previous_fd)
            if signal.getsignal(signal.SIGTERM) is ignore:  # (Ray's own handler stays)
                signal.signal(signal.SIGTERM, signal.SIG_DFL if previous_term is None
                              else previous_term)
        os.close(read_fd)
        os.close(write_fd)


def _check_feasible(ray, config: RayConfig) -> None:
    """A task no node can hold would wait forever: one line naming the flag instead."""
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive", True)]
    for flag, key, need in (("--ray-cpus", "CPU", config.cpus_per_task),
                            ("--ray-gpus", "GPU", config.gpus_per_task)):
        most = max((float(r.get(key, 0.0)) for r in nodes), default=0.0)
        if need > most:
            raise ValueError(f"{flag} {need:g}: no node of the Ray cluster has that many "
                             f"{key}s (the largest has {most:g})")


def _stop(ray, refs: list, timeout: float = 30.0) -> None:
    """Stops the other tasks once a unit failed for good, quietly.

    They are cancelled with ``force=True``: a running one's worker process is killed, as a
    lost worker would be (its unit file is written atomically, so a killed task leaves no
    partial unit), instead of a KeyboardInterrupt raised inside running JAX or MuJoCo code,
    which could abort the worker with a "Fatal Python error: Aborted" that Ray forwards to
    the driver's stderr. Their outcomes are then collected (up to ``timeout`` seconds), so
    that Ray logs no "Unhandled error" for a sibling that had failed too.
    """
    for ref in refs:
        ray.cancel(ref, force=True)
    done, _ = ray.wait(list(refs), num_returns=len(refs), timeout=timeout)
    for ref in done:
        try:
            ray.get(ref)
        except Exception:  # noqa: BLE001, S110 - cancelled or failed: already reported
            pass


def run_units(units: Sequence[Unit], config: RayConfig, run_dir: str | os.PathLike, *,
              log: Callable[[str], None] = print, progress: bool = True,
              desc: str = "units") -> dict[str, float]:
    """Runs ``units`` as Ray tasks and waits for all of them.

    Args:
      units: the units still to compute (the caller skips finished ones).
      config: resources, retries, address.
      run_dir: the run directory (the compilation cache's default home).
      log: where the one-line start message goes.
      progress: a progress bar over finished units.
      desc: the bar's label.

    Returns:
      unit name -> what its task reported (the last, successful attempt): ``seconds``,
      ``cpu_seconds`` (the worker process's user + system time over the unit), ``threads``
      (the process's threads after it), ``cores`` (pinned cores or None), ``pid``, ``host``.

    Raises:
      UnitFailedError: a unit failed for good (one line); the others are cancelled, and every
        unit finished before is on disk.
    """
    ray = require_ray()
    if not units:
        return {}
    started = _init(ray, config)
    try:
        _check_feasible(ray, config)
        env = worker_env(config, run_dir)
        options: dict[str, Any] = dict(num_cpus=config.cpus_per_task,
                                       num_gpus=config.gpus_per_task,
                                       max_retries=config.max_retries, retry_exceptions=False,
                                       runtime_env={"env_vars": env})
        if config.spread:
            options["scheduling_strategy"] = "SPREAD"
        task = ray.remote(_call_unit).options(**options)
        cpus = ray.cluster_resources().get("CPU", 0)
        log(f"Ray: {len(units)} {desc} as tasks of {config.cpus_per_task} CPU"
            f"{'s' if config.cpus_per_task > 1 else ''}"
            f"{f' + {config.gpus_per_task:g} GPU' if config.gpus_per_task else ''} on "
            f"{cpus:g} CPUs ({len(ray.nodes())} node{'s' if len(ray.nodes()) > 1 else ''})")
        refs = {task.remote(u.fn, tuple(u.args)): u for u in units}
        from tqdm.auto import tqdm

        bar = tqdm(total=len(units), unit=desc.rstrip("s") or "unit", desc="ray",
                   disable=not progress)
        seconds: dict[str, dict[str, Any]] = {}
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    unit = refs[ref]
                    try:
                        seconds[unit.name] = ray.get(ref)
                    except Exception as exc:  # noqa: BLE001 - any task failure is one line
                        _stop(ray, pending)
                        raise UnitFailedError(unit.name,
                                              _describe(exc, config.max_retries)) from None
                    bar.update(1)
        finally:
            bar.close()
        return seconds
    finally:
        if started:
            ray.shutdown()
