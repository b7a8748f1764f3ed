"""Exploration strategies as ``Learner(init, act, update)`` triples over a network passed in
(core: jax, numpy, optax only). ``base`` holds the interface, ``registry`` the names the
runners and ``sern grasp learn --policies`` accept; one module per learner."""

from sern_jax.learners import base, registry
from sern_jax.learners.base import (
    Batch, Buffer, Data, Learner, LearnerState, Model, Obs, TrainConfig)

__all__ = ["base", "registry", "Batch", "Buffer", "Data", "Learner", "LearnerState", "Model",
           "Obs", "TrainConfig"]
