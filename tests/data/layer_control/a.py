from sern_jax.core import fake_b  # noqa: F401
