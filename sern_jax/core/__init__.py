"""The pure core: bandit problems, policies, schedules and estimators.

Imports only jax, numpy, optax and scipy; no files, threads or environment variables. Modules
load on use (``from sern_jax.core import policies``).
"""
