"""Resting poses settle in threads (sern_jax.grasp.context): the same contexts bit for bit."""

import jax
import numpy as np

from sern_jax.grasp import context, objects


def _arrays(ctx) -> dict[str, np.ndarray]:
    out = {"poses": ctx.poses, "depth": ctx.depth}
    out.update({f"cand.{k}": np.asarray(v) for k, v in ctx.candidates._asdict().items()})
    return out


def test_threaded_contexts_equal_serial_bit_for_bit(monkeypatch):
    spec = objects.sample_population(3, 2)[1]
    config = context.ContextConfig(renderer="native")
    key = jax.random.key(11)
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "1")
    serial = _arrays(context.make_contexts(key, spec, 6, config))
    monkeypatch.setenv("SERN_CONTEXT_THREADS", "3")
    assert context.context_threads() == 3
    threaded = _arrays(context.make_contexts(key, spec, 6, config))
    assert 3 in context._POOLS  # the pool really ran the poses
    assert sorted(serial) == sorted(threaded)
    for k in serial:
        assert serial[k].dtype == threaded[k].dtype and serial[k].shape == threaded[k].shape
        assert serial[k].tobytes() == threaded[k].tobytes(), k
    assert len({tuple(p) for p in serial["poses"]}) == 6  # six different poses


def test_context_threads_follow_the_task_share(monkeypatch):
    monkeypatch.delenv("SERN_CONTEXT_THREADS", raising=False)
    monkeypatch.setenv("SERN_CPU_THREADS", "2")
    assert context.context_threads() == 2
