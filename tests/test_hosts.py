"""sern_jax.infra.hosts: the one reader of CPU counts and SERN_* variables."""

import os

from sern_jax.infra import hosts


def test_cpu_threads_follow_the_task_share(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(16)))
    monkeypatch.delenv("SERN_CPU_THREADS", raising=False)
    monkeypatch.delenv("SERN_CONTEXT_THREADS", raising=False)
    assert hosts.usable_cores() == 16 and hosts.cpu_threads() == 16
    assert hosts.many_cores()
    monkeypatch.setenv("SERN_CPU_THREADS", "3")
    assert hosts.cpu_threads() == 3 and hosts.context_threads() == 3
    assert not hosts.many_cores()  # a 3-CPU Ray task on a 16-core node
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "1")
    assert hosts.context_threads() == 1
    for junk in ("0", "-2", "abc", ""):  # ignored: the default applies
        monkeypatch.setenv("SERN_CPU_THREADS", junk)
        assert hosts.cpu_threads() == 16


def test_deterministic_xla_flags_are_added_once_and_the_user_wins(monkeypatch):
    monkeypatch.delenv("SERN_GPU_NONDETERMINISTIC", raising=False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert hosts.use_deterministic_xla()
    assert hosts.use_deterministic_xla()  # idempotent
    flags = os.environ["XLA_FLAGS"].split()
    assert flags == ["--xla_force_host_platform_device_count=2", *hosts.DETERMINISTIC_XLA_FLAGS]
    # a user's own value of one of the options is kept, and then they are not both in effect
    monkeypatch.setenv("XLA_FLAGS", "--xla_gpu_autotune_level=4")
    assert not hosts.use_deterministic_xla()
    assert "--xla_gpu_autotune_level=4" in os.environ["XLA_FLAGS"].split()
    assert "--xla_gpu_deterministic_ops=true" in os.environ["XLA_FLAGS"].split()
    # opting out leaves XLA_FLAGS alone
    monkeypatch.setenv("SERN_GPU_NONDETERMINISTIC", "1")
    monkeypatch.setenv("XLA_FLAGS", "")
    assert not hosts.use_deterministic_xla()
    assert os.environ["XLA_FLAGS"] == ""
