"""Theorem 1, statistical: E[N_a(t)] ≥ ct on a log grid of t (audit §2.3 (ii))."""

from __future__ import annotations

import numpy as np

from . import common
from . import framework as fw
from sern_jax.analysis import theory as th


def simulate(ctx):
    return common.t1_runs(ctx)


def evaluate(data, ctx):
    cells = []
    for (est, K, alpha), (out, times) in data["runs"].items():
        c = 1.0 / K if ctx.mutate else float(th.thm1_c(alpha, K))
        arm = int(np.argmin(out.counts[:, -1, :].mean(axis=0)))  # least-pulled arm at T
        for g, t in enumerate(times):
            if t < 10:
                continue
            cells.append(fw.mean_cell(f"{est} K={K} α={alpha:g} t={t} arm {arm}: E N_a(t)",
                                      out.counts[:, g, arm], c * t, "ge", ctx.alpha,
                                      vacuous=c * t < 1.0, value_range=(0.0, float(t))))
    return fw.finish(CHECK, ctx, cells, seeds=data["grid"]["seeds"],
                     notes="the tested arm is the least-pulled one at T (chosen after the "
                           "fact, which can only favour a FAIL)")


CHECK = fw.Check(
    name="t1_expected_count",
    claim="Thm 1: E[N_a(t)] ≥ ct, c = e^{−1/α}/K",
    configuration="the runs of t1_minprob_pathwise; checkpoints t ≥ 10; least-pulled arm",
    statistic="mean N_a(t) over seeds (Student t, upper one-sided 99% bound, Holm over cells)",
    bound="ct (VACUOUS where ct < 1)",
    expected=fw.HOLDS,
    simulate=simulate,
    evaluate=evaluate,
    mutation="c replaced by 1/K",
)
