from sern_jax.core import fake_a  # noqa: F401
