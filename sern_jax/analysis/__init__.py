"""Closed forms of the paper's theorems (``theory``), statistics over seeds (``stats``) and
the grasp benchmark's metrics and comparisons (``benchmark_stats``: objects as a random
factor, Holm, TOST, power)."""
