"""The ordered list of checks run by ``sern check``."""

from __future__ import annotations

import importlib

NAMES = (
    # engine-free (exact / analytic)
    "t2_exact_binomial",
    "t2_negative_control_8",
    "t4_c_consistency",
    # Theorem 1–2
    "t1_minprob_pathwise",
    "t1_expected_count",
    "t1_tightness_pinned",
    "t1_needs_clip",
    "t2_tail_mc",
    "t2_submartingale",
    # Theorem 3 and its ingredients
    "t3_inequality",
    "t3_no_misid_term",
    "t3_selection_bias",
    "a3_adaptive_addhalf",
    "t3_regret_definition",
    # Theorem 4
    "t4_bound_vs_regret",
    "t4_term3_flip",
    "t4_certified_alpha0_small",
    # Theorem 5 and Algorithm 1
    "t5_ratio_decreasing",
    "t5_alpha0_small",
    "t5_worst_case_rate",
    "alg1_l1_median",
    "alg1_argmax_literal",
    # the paper's experimental setting
    "exp_fixed_alpha",
    # Theorems 1, 3, 4, Assumption 3 and Algorithm 1 on a real neural estimator
    "n1_neural_floor",
    "a3_neural_error",
    "t3_neural_inequality",
    "t4_neural_bound",
    "alg1_neural_argmax",
)


def get(name: str):
    if name not in NAMES:
        raise ValueError(f"unknown check {name!r}; choose from {', '.join(NAMES)}")
    return importlib.import_module(f"{__package__}.{name}").CHECK


def all_checks(only=None):
    names = NAMES if not only else [n for n in NAMES if n in set(only)]
    if only:
        for n in only:
            get(n)  # raises on unknown names
    return [get(n) for n in names]
