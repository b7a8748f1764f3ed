"""The grasp-exploration benchmark's metrics and statistics, as pure numpy/scipy functions.

A benchmark run gives, per object o, learner q and seed s, the fixed-pose greedy success
after every round (``lowvar_eval`` [R + 1, O, Q, S], round 0 = θ0) and the fraction of each
round's exploration grasps that succeeded (``explore_success``, round 0 NaN). The metrics
(:func:`run_metrics`), in percentage points:

* ``curve_area`` (primary): mean over rounds 1..R of the fixed-pose greedy success, the area
  under the learning curve;
* ``explore_success`` (primary): mean over rounds 1..R of the exploration success, the bandit's
  own reward (successes over exploration grasps);
* ``round5`` (secondary): the fixed-pose greedy success after the last round;
* ``grasps_to_80`` (secondary, in exploration grasps): explore × the first round r >= 1 whose
  fixed-pose greedy success is at least 80 %; a seed that never gets there is *censored* at
  R × explore + explore, so a mean of this metric is a lower bound where any seed is censored.

Comparisons a − b are paired per seed (common random numbers: within a seed, every learner
sees the same poses, candidates and trial noise), d[o, s] = metric[o, a, s] − metric[o, b, s].
Objects are a random factor (:func:`object_level`): each object's mean over seeds
m_o = mean_s d[o, s], the difference is mean_o m_o, and its interval is Student t over the O
object means (O − 1 degrees of freedom), so the claim covers objects drawn like these, not
only these. The per-object intervals of a forest plot are Student t over seeds (S − 1 degrees
of freedom; :func:`per_object`). :func:`compare` runs every comparison of a reference learner
against the others with Holm's correction within each family (primary: the two primary
metrics × the other learners; secondary: the two secondary metrics × the other learners) and
a TOST equivalence test (:func:`tost`) at ± :data:`TOST_MARGIN` points on the object-level
difference. :func:`detectable_difference` is the power statement of the pre-registration.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy import stats as sps

from sern_jax.analysis import stats

__all__ = [
    "PRIMARY",
    "SECONDARY",
    "METRICS",
    "UNITS",
    "THRESHOLD",
    "TOST_MARGIN",
    "LEVEL",
    "run_metrics",
    "ObjectLevel",
    "object_level",
    "per_object",
    "Tost",
    "tost",
    "compare",
    "learner_means",
    "curves",
    "Detectable",
    "power",
    "detectable_difference",
]

PRIMARY = ("curve_area", "explore_success")
SECONDARY = ("round5", "grasps_to_80")
METRICS = PRIMARY + SECONDARY
UNITS = {"curve_area": "percentage points", "explore_success": "percentage points",
         "round5": "percentage points", "grasps_to_80": "exploration grasps"}
THRESHOLD = 0.8  # grasps_to_80's fixed-pose greedy success
TOST_MARGIN = 2.0  # percentage points, both sides
LEVEL = 0.95  # two-sided confidence level of every interval; tests at 1 − LEVEL


def run_metrics(lowvar_eval, explore_success, explore: int,
                threshold: float = THRESHOLD) -> dict[str, np.ndarray]:
    """The benchmark's metrics of every copy of a run.

    Args:
      lowvar_eval: [R + 1, ...] fixed-pose greedy success (fractions; round 0 = θ0).
      explore_success: [R + 1, ...] exploration success (fractions; round 0 unused).
      explore: exploration grasps per round.
      threshold: grasps_to_80's success level.

    Returns:
      metric name -> [...] float64: ``curve_area``, ``explore_success`` and ``round5`` in
      percentage points, ``grasps_to_80`` in exploration grasps (censored at
      (R + 1) × explore where the threshold is never reached).
    """
    lv = np.asarray(lowvar_eval, np.float64)
    ex = np.asarray(explore_success, np.float64)
    if lv.shape != ex.shape:
        raise ValueError(f"lowvar_eval {lv.shape} and explore_success {ex.shape} differ")
    if lv.ndim < 1 or lv.shape[0] < 2:
        raise ValueError(f"need rounds 0..R with R >= 1 on axis 0, got shape {lv.shape}")
    if isinstance(explore, bool) or int(explore) != explore or explore < 1:
        raise ValueError(f"explore must be an integer >= 1, got {explore!r}")
    if not (np.all(np.isfinite(lv)) and np.all(np.isfinite(ex[1:]))):
        raise ValueError("rounds 1..R hold NaN: the run has not finished every round")
    rounds = lv.shape[0] - 1
    reached = lv[1:] >= threshold  # [R, ...]
    first = np.where(reached.any(0), reached.argmax(0) + 1, rounds + 1)
    return {"curve_area": 100.0 * lv[1:].mean(0),
            "explore_success": 100.0 * ex[1:].mean(0),
            "round5": 100.0 * lv[-1],
            "grasps_to_80": (first * int(explore)).astype(np.float64)}


class ObjectLevel(NamedTuple):
    """A paired difference with objects as a random factor (arrays over leading axes)."""

    diff: np.ndarray  # mean over objects of the objects' means over seeds
    se: np.ndarray  # SD of the O object means / √O
    df: int  # O − 1
    half: np.ndarray  # t_{(1+level)/2, O−1} · se
    ci_low: np.ndarray
    ci_high: np.ndarray
    p: np.ndarray  # two-sided t test of diff = 0
    n_objects: int
    n_seeds: int
    object_means: np.ndarray  # [..., O]


def _t_stat(mean, se, null=0.0):
    """(mean − null)/se, with se = 0 read as exact (0 where mean == null, ±inf otherwise)."""
    mean, se = np.asarray(mean, np.float64), np.asarray(se, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = mean - null
        return np.where(se > 0, gap / np.where(se > 0, se, 1.0),
                        np.where(gap == 0, 0.0, np.sign(gap) * np.inf))


def object_level(d, level: float = LEVEL) -> ObjectLevel:
    """Objects as a random factor: the interval over the O object means.

    Args:
      d: [..., O, S] paired per-seed differences (finite).
      level: two-sided confidence level.

    Returns:
      :class:`ObjectLevel` over the leading axes (floats for a 2-D ``d``).
    """
    d = np.asarray(d, np.float64)
    if d.ndim < 2:
        raise ValueError(f"need [..., objects, seeds] differences, got shape {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("per-seed differences contain NaN or inf")
    n_obj, n_seeds = d.shape[-2:]
    if n_obj < 2 or n_seeds < 1:
        raise ValueError(f"objects as a random factor need >= 2 objects, got {n_obj}")
    means = d.mean(-1)
    ci = stats.t_interval(means, level, axis=-1)
    t = _t_stat(ci.mean, ci.se)
    p = 2.0 * sps.t.sf(np.abs(t), n_obj - 1)
    out = ObjectLevel(ci.mean, ci.se, n_obj - 1, ci.half, ci.lower, ci.upper, p, n_obj,
                      n_seeds, means)
    if d.ndim == 2:
        return out._replace(**{k: float(getattr(out, k)) for k in
                               ("diff", "se", "half", "ci_low", "ci_high", "p")})
    return out


def per_object(d, level: float = LEVEL) -> stats.SeedInterval:
    """Each object's Student-t interval over its seeds (S − 1 degrees of freedom): the forest
    plot's rows. ``d``: [..., S] paired per-seed differences; the fields are [...]."""
    return stats.t_interval(np.asarray(d, np.float64), level, axis=-1)


class Tost(NamedTuple):
    """Two one-sided t tests of |true difference| >= margin (equivalence when both reject)."""

    margin: float
    p_lower: float  # H0: diff <= −margin, rejected for large diff
    p_upper: float  # H0: diff >= +margin, rejected for small diff
    p: float  # max(p_lower, p_upper)
    equivalent: bool  # p < alpha


def tost(diff, se, df: int, margin: float = TOST_MARGIN, alpha: float = 1.0 - LEVEL):
    """TOST equivalence test of a t-distributed estimate (two one-sided t tests, ``df``
    degrees of freedom); with se = 0 the estimate is read as exact.

    Returns:
      :class:`Tost` of floats for scalar inputs, of arrays otherwise.
    """
    if not margin > 0:
        raise ValueError(f"margin must be > 0, got {margin!r}")
    if int(df) < 1:
        raise ValueError(f"a t test needs df >= 1, got {df!r}")
    p_lower = sps.t.sf(_t_stat(diff, se, -margin), df)
    p_upper = sps.t.cdf(_t_stat(diff, se, margin), df)
    p = np.maximum(p_lower, p_upper)
    out = Tost(float(margin), p_lower, p_upper, p, p < alpha)
    if np.ndim(p) == 0:
        return Tost(float(margin), float(p_lower), float(p_upper), float(p), bool(p < alpha))
    return out


def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def compare(metrics: dict, learners, objects, reference: str = "sern",
            primary=PRIMARY, secondary=SECONDARY, margin: float = TOST_MARGIN,
            level: float = LEVEL) -> tuple[list[dict], list[dict]]:
    """``reference`` against every other learner on each metric.

    Args:
      metrics: metric name -> [O, Q, S] per-seed values (``run_metrics``' units).
      learners: the Q learner names (the Q axis).
      objects: the O object names.
      reference: learner ``a`` of every comparison (a − b).
      primary, secondary: the metrics of the two Holm families.
      margin: the TOST margin, in percentage points (applied to the metrics measured in
        percentage points; ``grasps_to_80`` gets no TOST: its fields are None).
      level: two-sided confidence level; Holm and TOST test at 1 − level.

    Returns:
      (comparisons, per_object): one dict per (metric, other learner) with ``a``, ``b``,
      ``metric``, ``diff``, ``ci_low``, ``ci_high``, ``se``, ``df``, ``p``, ``holm_p``,
      ``family``, ``level`` ("objects"), ``n_objects``, ``n_seeds`` and ``tost``; and one
      dict per (metric, other learner, object) with the t interval over seeds.
    """
    learners, objects = list(learners), list(objects)
    if reference not in learners:
        raise ValueError(f"reference learner {reference!r} is not among {learners}")
    if len(learners) < 2:
        raise ValueError("comparisons need at least two learners")
    if set(primary) & set(secondary):
        raise ValueError("a metric is in both families")
    a = learners.index(reference)
    others = [q for q in range(len(learners)) if q != a]
    alpha = 1.0 - level
    comparisons, rows = [], []
    for family, names in (("primary", primary), ("secondary", secondary)):
        fam = []
        for metric in names:
            if metric not in metrics:
                raise ValueError(f"no per-seed values of metric {metric!r}")
            x = np.asarray(metrics[metric], np.float64)
            if x.shape[:2] != (len(objects), len(learners)):
                raise ValueError(f"{metric}: shape {x.shape} is not [objects {len(objects)}, "
                                 f"learners {len(learners)}, seeds]")
            for b in others:
                d = x[:, a] - x[:, b]  # [O, S]
                ol = object_level(d, level)
                if UNITS.get(metric) == "percentage points":
                    tt = tost(ol.diff, ol.se, ol.df, margin, alpha)._asdict()
                else:
                    tt = {"margin": None, "p_lower": None, "p_upper": None, "p": None,
                          "equivalent": None}
                fam.append({"a": reference, "b": learners[b], "metric": metric,
                            "diff": ol.diff, "ci_low": ol.ci_low, "ci_high": ol.ci_high,
                            "se": ol.se, "df": ol.df, "p": ol.p, "holm_p": None,
                            "family": family, "level": "objects",
                            "n_objects": ol.n_objects, "n_seeds": ol.n_seeds, "tost": tt})
                po = per_object(d, level)
                for o, name in enumerate(objects):
                    rows.append({"a": reference, "b": learners[b], "metric": metric,
                                 "object": name, "diff": float(po.mean[o]),
                                 "ci_low": _finite(po.lower[o]),
                                 "ci_high": _finite(po.upper[o]), "n": int(po.n)})
        _, adjusted = stats.holm([c["p"] for c in fam], alpha)
        for c, p_holm in zip(fam, adjusted):
            c["holm_p"] = float(p_holm)
        comparisons += fam
    return comparisons, rows


def learner_means(metrics: dict, learners, level: float = LEVEL) -> dict:
    """learner -> metric -> mean over objects of the objects' means over seeds, with its
    standard error and t half-width over the objects (O − 1 degrees of freedom)."""
    out = {name: {} for name in learners}
    for metric, x in metrics.items():
        x = np.asarray(x, np.float64)
        ci = stats.t_interval(x.mean(-1), level, axis=0)  # [Q] over objects
        for q, name in enumerate(learners):
            out[name][metric] = {"mean": float(ci.mean[q]), "se": _finite(ci.se[q]),
                                 "half": _finite(ci.half[q]), "n_objects": int(x.shape[0])}
    return out


def curves(lowvar_eval, learners, level: float = LEVEL) -> dict:
    """learner -> round (a string, "0" = θ0) -> the fixed-pose greedy success in percent,
    mean over objects and seeds, with the standard error and t half-width over the objects'
    means (O − 1 degrees of freedom). ``lowvar_eval``: [R + 1, O, Q, S] fractions."""
    lv = 100.0 * np.asarray(lowvar_eval, np.float64).mean(-1)  # [R + 1, O, Q]
    ci = stats.t_interval(lv, level, axis=1)  # [R + 1, Q]
    return {name: {str(r): {"mean": float(ci.mean[r, q]), "se": _finite(ci.se[r, q]),
                            "half": _finite(ci.half[r, q])}
                   for r in range(lv.shape[0])}
            for q, name in enumerate(learners)}


class Detectable(NamedTuple):
    """The smallest true difference a two-sided t test detects with the given power."""

    diff: float  # in the units of the SDs
    se: float  # standard error of the estimate
    df: int
    alpha: float  # the test's level after the family correction
    power: float
    method: str


def _design(sd_seed, sd_object, num_objects, num_seeds):
    for name, v in (("num_objects", num_objects), ("num_seeds", num_seeds)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    if not (sd_seed >= 0 and sd_object >= 0):
        raise ValueError("standard deviations must be >= 0")
    o, s = int(num_objects), int(num_seeds)
    if o == 1:  # one object: the per-object test over seeds
        if s < 2:
            raise ValueError("one object needs >= 2 seeds")
        return float(sd_seed) / math.sqrt(s), s - 1
    return math.sqrt((sd_object ** 2 + sd_seed ** 2 / s) / o), o - 1


def power(diff: float, sd_seed: float, sd_object: float, num_objects: int, num_seeds: int,
          alpha: float = 1.0 - LEVEL, family_size: int = 1) -> float:
    """Power of the two-sided object-level t test (:func:`object_level`) at a true
    difference ``diff``: P(|T| > t_{1 − α'/2, df}) for T noncentral t with noncentrality
    diff / se (``scipy.stats.nct``), α' = alpha / family_size (Holm's strictest step).

    The design: d[o, s] = diff + u_o + e_os with u_o ~ N(0, sd_object²) (between objects) and
    e_os ~ N(0, sd_seed²) (seed to seed), so the object means are i.i.d. with variance
    sd_object² + sd_seed²/S and se = √((sd_object² + sd_seed²/S)/O), df = O − 1. With one
    object it is the per-object test over seeds: se = sd_seed/√S, df = S − 1.
    """
    se, df = _design(sd_seed, sd_object, num_objects, num_seeds)
    a = _alpha(alpha, family_size)
    crit = float(sps.t.ppf(1.0 - a / 2.0, df))
    if se == 0:
        return 1.0 if diff != 0 else a
    nc = abs(float(diff)) / se
    return float(sps.nct.sf(crit, df, nc) + sps.nct.cdf(-crit, df, nc))


def _alpha(alpha, family_size) -> float:
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    if isinstance(family_size, bool) or int(family_size) != family_size or family_size < 1:
        raise ValueError(f"family_size must be an integer >= 1, got {family_size!r}")
    return float(alpha) / int(family_size)


def detectable_difference(sd_seed: float, sd_object: float, num_objects: int,
                          num_seeds: int, alpha: float = 1.0 - LEVEL, family_size: int = 1,
                          power_goal: float = 0.8) -> Detectable:
    """The smallest true difference the object-level test detects with ``power_goal``, at
    level alpha / family_size (Holm's first step: the bound every comparison of the family
    meets). Exact under the design of :func:`power` (noncentral t, ``scipy.stats.nct``).

    Args:
      sd_seed: SD over seeds of one object's paired per-seed differences.
      sd_object: SD between objects of the true per-object differences.
      num_objects, num_seeds: O and S.
      alpha: the family's level (two-sided).
      family_size: m, the comparisons Holm corrects over.
      power_goal: the power to reach.
    """
    from scipy.optimize import brentq

    if not 0.0 < power_goal < 1.0:
        raise ValueError(f"power_goal must be in (0, 1), got {power_goal!r}")
    se, df = _design(sd_seed, sd_object, num_objects, num_seeds)
    a = _alpha(alpha, family_size)
    method = "noncentral t, two-sided"
    if se == 0:
        return Detectable(0.0, 0.0, df, a, power_goal, method)

    def gap(nc):
        return power(nc * se, sd_seed, sd_object, num_objects, num_seeds, a) - power_goal

    hi = float(sps.t.ppf(1.0 - a / 2.0, df) + sps.norm.ppf(power_goal)) + 1.0
    while gap(hi) < 0:
        hi *= 2.0
    nc = brentq(gap, 0.0, hi, xtol=1e-10)
    return Detectable(float(nc * se), se, df, a, float(power_goal), method)
