"""Shared type aliases.

Legend for shapes in docstrings: ``S`` seeds, ``T`` horizon, ``G`` checkpoints, ``K`` arms,
``M`` contexts.
"""

from __future__ import annotations

import jax

Array = jax.Array
Key = jax.Array

__all__ = ["Array", "Key"]
