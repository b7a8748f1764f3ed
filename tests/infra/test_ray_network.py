"""What ``--ray`` exposes and how long it may wait (sern_jax/infra/distributed.py): the local
Ray listens on loopback only, and joining a cluster address is bounded in time and ends on
SIGTERM, in one line naming ``--ray``, with nothing written."""

from __future__ import annotations

import ipaddress
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TAB = ["regret", "--policies", "softmax", "--arms", "3", "--horizon", "20", "--seeds", "2",
       "--no-progress", "--no-figures", "--out", "run"]
JOIN = ("import sys, ray\n"
        "from sern_jax.infra import distributed\n"
        "print('joining', flush=True)\n"
        "distributed.join(ray, sys.argv[1], timeout=float(sys.argv[2]))\n"
        "print('joined', flush=True)\n")


def _listening(pid: int) -> list[tuple[str, int, str]]:
    """(address, port, process name) of every listening TCP socket of ``pid`` and of the
    processes it started."""
    import psutil

    me = psutil.Process(pid)
    found = []
    for proc in [me, *me.children(recursive=True)]:
        try:
            conns = proc.net_connections(kind="tcp")
            name = proc.name()
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        found += [(c.laddr.ip, c.laddr.port, name) for c in conns
                  if c.status == psutil.CONN_LISTEN]
    return found


def _loopback(ip: str) -> bool:
    addr = ipaddress.ip_address(ip.split("%")[0])
    mapped = getattr(addr, "ipv4_mapped", None)
    return addr.is_loopback or (mapped is not None and mapped.is_loopback)


def test_local_ray_listens_on_loopback_only():
    """Every server of the local Ray that ``--ray`` starts (GCS, raylet and object manager,
    the driver's and a worker's gRPC servers, the agents) listens on 127.0.0.1 only."""
    ray = pytest.importorskip("ray")
    pytest.importorskip("psutil")
    if ray.is_initialized():
        pytest.skip("a Ray is already running in this process")
    from sern_jax.infra import distributed

    def pid() -> int:
        return os.getpid()

    assert distributed._init(ray, distributed.RayConfig(workers=1)) is True
    try:
        assert ray.get(ray.remote(pid).remote()) != os.getpid()  # a worker runs
        sockets = _listening(os.getpid())
    finally:
        ray.shutdown()
    assert len(sockets) >= 4, sockets  # GCS, raylet (2), the driver, a worker, ...
    exposed = [s for s in sockets if not _loopback(s[0])]
    assert not exposed, f"listening beyond loopback: {exposed}"


def _silent_address() -> tuple[socket.socket, str]:
    """A TCP port that accepts connections (the kernel completes them) and never answers."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(64)
    return server, f"127.0.0.1:{server.getsockname()[1]}"


def test_join_of_a_silent_address_ends_in_one_line_within_its_bound(tmp_path):
    pytest.importorskip("ray")
    server, address = _silent_address()
    with server:
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", JOIN, address, "3"], cwd=tmp_path,
                             capture_output=True, text=True, timeout=120,
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert out.returncode == 2, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"--ray {address}: ") and \
        "within 3 s" in lines[0], out.stderr
    assert "joined" not in out.stdout and list(tmp_path.iterdir()) == []
    assert time.perf_counter() - t0 < 60


def test_join_ends_on_sigterm_in_one_line(tmp_path):
    pytest.importorskip("ray")
    server, address = _silent_address()
    with server:
        proc = subprocess.Popen([sys.executable, "-c", JOIN, address, "300"], cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONPATH": str(ROOT)})
        try:
            assert proc.stdout.readline().strip() == "joining"
            time.sleep(3)  # inside ray.init, in Ray's connection loop
            proc.send_signal(signal.SIGTERM)
            t0 = time.perf_counter()
            _, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
    assert time.perf_counter() - t0 < 10
    assert proc.returncode == 128 + signal.SIGTERM, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "SIGTERM" in lines[0] and f"--ray {address}" in lines[0], err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # the command's bound: 30 s of joining after its start
def test_regret_on_a_silent_address_is_refused_within_the_bound(tmp_path):
    """``sern regret --ray HOST:PORT`` where something accepts connections but no Ray
    answers: exit 2 within the stated bounds, one line naming --ray, nothing written."""
    pytest.importorskip("ray")
    from sern_jax.infra import distributed

    server, address = _silent_address()
    with server:
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "sern_jax.commands.main", *TAB, "--ray",
                              address], cwd=tmp_path, capture_output=True, text=True,
                             timeout=200, env={**os.environ, "PYTHONPATH": str(ROOT)})
    seconds = time.perf_counter() - t0
    assert out.returncode == 2, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and f"--ray {address}" in lines[0], out.stderr
    assert list(tmp_path.iterdir()) == []
    assert seconds < distributed.JOIN_TIMEOUT_S + 30  # + Python, JAX and Ray imports
