"""The one timing helper (sern_jax.infra.timing) and the one machine description (io.machine)."""

import time

import jax.numpy as jnp
import pytest

from sern_jax.infra import io, timing


def test_time_calls_counts_calls_and_times_the_first_apart():
    calls = []

    def call():
        calls.append(1)
        time.sleep(0.02 if len(calls) == 1 else 0.001)
        return jnp.ones(3) * len(calls)

    t = timing.time_calls(call, repeats=4, warmup=1)
    assert len(calls) == 5 and len(t.times_s) == 4 and len(t.cpu_s) == 4
    assert t.first_s >= 0.02 > t.best_s  # the slow first call is not among the timed ones
    assert t.overhead_s == pytest.approx(t.first_s - t.best_s)
    assert float(t.result[0]) == 5.0
    s = t.stats()
    assert s["min_s"] <= s["median_s"] <= s["max_s"] and len(s["times_s"]) == 4


def test_time_calls_min_time_gives_seconds_per_call():
    n = []
    t = timing.time_calls(lambda: n.append(time.sleep(0.002)), repeats=2, warmup=0,
                          min_calls=3, min_time=0.03)
    assert t.first_s is None
    assert len(n) >= 2 * 10  # >= 30 ms of 2 ms calls per round
    assert 0.0015 < t.median_s < 0.02  # per call, not per round


def test_time_calls_rejects_bad_counts():
    with pytest.raises(ValueError):
        timing.time_calls(lambda: None, repeats=0)


def test_machine_describes_this_host():
    m = io.machine()
    assert m["cpu"] and m["cpu_count"] >= 1 and m["python"] and m["platform"]
    assert "jax_backend" not in m
    d = io.machine(devices=True)
    assert d["jax_backend"] == "cpu" or d["jax_devices"]
    assert io.run_metadata()["host"]["cpu"] == m["cpu"]
