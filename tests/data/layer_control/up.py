from sern_jax.engine import drive  # noqa: F401
