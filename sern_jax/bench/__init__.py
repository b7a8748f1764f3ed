"""Benchmarks, imported only by ``sern bench``: the bandit engines against the naive
``jit(vmap(scan))`` and a NumPy reference (``bandit``), neural learners (``neural``) and the
grasp simulator and renderer (``grasp``)."""
