"""sern_jax: SERN (Shannon-entropy-regularised neural contextual bandits) in JAX.

Core modules (jax, numpy, optax only): ``policies``, ``schedules``, ``estimators``,
``problems``, ``simulate``, ``sharding``, ``theory``, ``stats``, ``io``. The grasp layer
(``sern_jax.grasp``) imports mujoco, mjx and flax and is not imported here.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
