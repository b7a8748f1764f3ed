"""Common machinery for proofs_check: check declarations, cells, verdicts, cached runs.

A *check* declares the claim it tests, the configuration, the statistic, the bound and the
expected verdict (HOLDS: the paper's claim should survive; FAILS: a negative control or a
counterexample, which must be rejected). It is split into

* ``simulate(ctx) -> dict``: the expensive part (engine runs, exact sums), cached per size, and
* ``evaluate(data, ctx) -> CheckResult``: cheap statistics against the bound.

Means over seeds (``mean_cell``, ``equal_cell``) take Student's t with n − 1 degrees of
freedom, interval and p-value alike (the project's rule for intervals over seeds); ratios and
slopes take a BCa bootstrap interval with a Student-t p-value on its spread
(``bootstrap_cell``), tail probabilities Clopper–Pearson.

``ctx.mutate`` swaps in a deliberately wrong bound (described by ``Check.mutation``), so the
tests can show that every check family is able to fail on the same data.

Each comparison is a :class:`Cell`. Statistical cells carry a one-sided p-value of "the claim
holds in this cell"; a family is corrected with Holm at ``ctx.alpha`` (audit §2.2). Verdicts:

* PASS — no cell rejected, and at least one cell had power;
* FAIL — some cell rejected (exact cells: a pathwise violation beyond 1e-9 relative);
* UNINFORMATIVE — no cell rejected but no cell had power (e.g. a tail bound < 3/S);
* VACUOUS — no cell rejected, but every bound is at least the trivial bound (or the statistic
  cannot exceed the bound by construction), so passing carries no information.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

PASS, FAIL, UNINFORMATIVE, VACUOUS = "PASS", "FAIL", "UNINFORMATIVE", "VACUOUS"
HOLDS, FAILS = "HOLDS", "FAILS"
REL_TOL = 1e-9  # STYLE.md tolerance policy for float64 theory bounds


@dataclasses.dataclass
class Context:
    """Run-time options shared by all checks."""

    quick: bool = False
    seeds: int | None = None  # overrides every check's default seed count
    alpha: float = 0.01  # family-wise error rate (99% one-sided)
    mutate: bool = False  # use the deliberately wrong bound
    root_seed: int = 0
    progress: Callable[[str], None] | None = None

    def num_seeds(self, full: int, quick: int) -> int:
        if self.seeds is not None:
            return int(self.seeds)
        return quick if self.quick else full

    def note(self, msg: str) -> None:
        if self.progress is not None:
            self.progress(msg)


@dataclasses.dataclass
class Cell:
    """One comparison statistic-vs-bound inside a check.

    ``direction``: 'le' means the claim is statistic <= bound, 'ge' statistic >= bound,
    'eq' two-sided equality (tightness checks).
    """

    label: str
    statistic: float
    bound: float
    direction: str = "le"
    lower: float = math.nan  # CI of the statistic (nan for exact cells)
    upper: float = math.nan
    pvalue: float = math.nan  # one-sided p-value of "claim holds"; nan = exact cell
    exact: bool = False
    violated: bool = False  # exact cells: pathwise violation
    informative: bool = True  # the test had power here
    vacuous: bool = False  # bound >= trivial bound, or the statistic cannot exceed it
    detectable: float = math.nan  # smallest violation detectable (same units as statistic)
    expect: str | None = None  # optional per-cell expectation (PASS / FAIL)
    info_only: bool = False  # reported, not part of the verdict
    note: str = ""
    verdict: str = ""
    n: int = 0  # seeds behind a mean or equality cell (0: not a mean over seeds)
    se: float = math.nan  # its standard error sd/√n (ddof 1): intervals recomputable from the report

    def slack(self) -> float:
        """Relative margin in the claim's favour (negative = on the violating side)."""
        scale = max(abs(self.bound), 1e-300)
        if self.direction == "le":
            return (self.bound - self.statistic) / scale
        if self.direction == "ge":
            return (self.statistic - self.bound) / scale
        return -abs(self.statistic - self.bound) / scale


@dataclasses.dataclass
class CheckResult:
    name: str
    claim: str
    configuration: str
    statistic: str
    bound: str
    expected: str
    verdict: str
    cells: list[Cell]
    headline: str
    power: str
    by_construction: str | None
    family_size: int
    seeds: int
    wall_s: float = 0.0
    mutated: bool = False
    mutation: str = ""
    notes: str = ""
    figure_data: dict = dataclasses.field(default_factory=dict)

    @property
    def cells_ok(self) -> bool:
        return all(c.expect is None or c.expect == c.verdict for c in self.cells)

    @property
    def ok(self) -> bool:
        """Verdict equals the expectation: HOLDS -> not FAIL; FAILS -> FAIL; and every cell
        with its own expectation matches it."""
        if self.expected == HOLDS:
            good = self.verdict != FAIL
        else:
            good = self.verdict == FAIL
        return good and self.cells_ok

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["ok"] = self.ok
        d.pop("figure_data", None)
        return d


@dataclasses.dataclass(frozen=True)
class Check:
    name: str
    claim: str
    configuration: str
    statistic: str
    bound: str
    expected: str
    simulate: Callable[[Context], dict]
    evaluate: Callable[[dict, Context], dict]
    mutation: str
    by_construction: str | None = None
    needs_engine: bool = True


# ---------------------------------------------------------------------------------------
# Cell builders
# ---------------------------------------------------------------------------------------


def exact_cell(label, statistic, bound, direction="ge", vacuous=False, **kw) -> Cell:
    """Deterministic (pathwise or closed-form) comparison with relative tolerance 1e-9."""
    s, b = float(statistic), float(bound)
    tol = REL_TOL * max(abs(b), abs(s), 1e-300) if math.isfinite(s) and math.isfinite(b) else 0.0
    if direction == "ge":
        violated = s < b - tol
    elif direction == "le":
        violated = s > b + tol
    else:
        violated = abs(s - b) > tol
    return Cell(label, s, b, direction, exact=True, violated=violated, vacuous=vacuous, **kw)


def _seed_values(values) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64).ravel()
    if x.size < 2:
        raise ValueError(f"need at least 2 per-seed values for a t interval, got {x.size}")
    return x


def mean_cell(label, values, bound, direction="le", alpha=0.01, vacuous=False,
              value_range=None, **kw) -> Cell:
    """One-sided Student-t test (n − 1 degrees of freedom) of E[X] <= bound ('le') or
    >= bound ('ge') from per-seed values [S].

    The interval stored is the tested end one-sided at 1 − alpha (``stats.t_interval`` at
    1 − 2·alpha) and the other end two-sided at 1 − alpha; the p-value is the matching
    one-sided t-test (``stats.t_pvalue``), so the interval excludes the bound iff p <= alpha
    (before Holm), and ``detectable`` is the t-test's 80%-power excess.

    ``value_range=(lo, hi)``: the values' a-priori range. When every seed gives the same value
    v there is no variance to work with; then (if the range is known) the test is exact:
    if a fraction q of the population differs from v, all S seeds equal v with probability
    (1-q)^S, and a difference moves the mean by at most (hi - v) or (v - lo). Without a range
    the statistic is treated as deterministic (e.g. an exact oracle).
    """
    from sern_jax.analysis import stats

    x = _seed_values(values)
    ci = stats.t_interval(x, 1.0 - alpha)  # two-sided 1 − alpha
    one = stats.t_interval(x, 1.0 - 2.0 * alpha)  # its ends are one-sided 1 − alpha bounds
    p = stats.t_pvalue(ci.mean, ci.se, x.size, float(bound), direction)
    lo, hi = (one.lower, ci.upper) if direction == "le" else (ci.lower, one.upper)
    note_extra = ""
    if ci.se == 0.0 and value_range is not None:
        v, n, b = ci.mean, x.size, float(bound)
        q_alpha = 1.0 - alpha ** (1.0 / n)  # largest q with (1-q)^n >= alpha
        room = (value_range[1] - v) if direction == "ge" else (v - value_range[0])
        lo, hi = ((v - q_alpha * room, v + q_alpha * (value_range[1] - v)) if direction == "le"
                  else (v - q_alpha * (v - value_range[0]), v + q_alpha * room))
        gap = (b - v) if direction == "ge" else (v - b)
        if gap <= 0:
            p = 1.0
        elif room <= 0:
            p = 0.0
        else:
            p = float((1.0 - min(1.0, gap / room)) ** n)
        note_extra = "all seeds equal: exact zero-variance test"
    exc = stats.t_detectable_excess(ci.se, x.size, alpha)
    det = float(bound) + exc if direction == "le" else float(bound) - exc
    if note_extra:
        kw["note"] = (kw.get("note", "") + "; " + note_extra).lstrip("; ")
    return Cell(label, ci.mean, float(bound), direction, lower=lo, upper=hi, pvalue=p,
                detectable=det, vacuous=vacuous, n=x.size, se=ci.se, **kw)


def equal_cell(label, values, target, alpha=0.01, **kw) -> Cell:
    """Two-sided Student-t test (n − 1 degrees of freedom) of E[X] = target (tightness
    checks), with the two-sided 1 − alpha t interval."""
    from scipy.stats import t as student_t

    from sern_jax.analysis import stats

    x = _seed_values(values)
    ci = stats.t_interval(x, 1.0 - alpha)
    if ci.se > 0:
        p = float(2.0 * student_t.sf(abs(ci.mean - target) / ci.se, x.size - 1))
    else:
        p = 0.0 if abs(ci.mean - target) > REL_TOL * abs(target) else 1.0
    return Cell(label, ci.mean, float(target), "eq", lower=ci.lower, upper=ci.upper,
                pvalue=min(1.0, p),
                detectable=stats.t_detectable_excess(ci.se, x.size, alpha / 2), n=x.size,
                se=ci.se, **kw)


def tail_cell(label, k, n, bound, alpha=0.01, **kw) -> Cell:
    """Clopper–Pearson test of P(event) <= bound from k events in n seeds (audit §2.2)."""
    from sern_jax.analysis import stats

    k, n, b = int(k), int(n), float(bound)
    _, hi = stats.clopper_pearson(k, n, 1.0 - alpha, side="two")
    lo1, _ = stats.clopper_pearson(k, n, 1.0 - alpha, side="lower")
    p = float(stats.tail_pvalue(k, n, b))
    detect = float(stats.tail_detectable_prob(n, b, alpha))
    informative = b >= 3.0 / n and detect < 1.0
    return Cell(label, k / n, b, "le", lower=float(np.asarray(lo1)), upper=float(np.asarray(hi)),
                pvalue=p, informative=informative, detectable=detect, **kw)


def bootstrap_cell(label, data, fn, bound, direction="le", alpha=0.01, seed=0,
                   num_resamples=2000, **kw) -> Cell:
    """BCa bootstrap test of fn(column means) <= / >= bound from per-seed rows ``data``
    [S, d] (rows resampled together: a ratio or slope of means over seeds).

    The interval stored is BCa: the tested end one-sided at 1 − alpha, the other end
    two-sided at 1 − alpha (as in :func:`mean_cell`). The p-value and ``detectable`` are
    Student t with S − 1 degrees of freedom (the rule for intervals over seeds, as in
    :func:`mean_cell`) on the standard error that the two-sided BCa interval implies, se =
    half-width / t_{1 − alpha/2, S − 1}: a bound one half-width from the estimate gets
    p = alpha/2 (the BCa interval may be asymmetric; the p-value's fit is not).
    (Until 2026-11-24 the same fit used normal quantiles.) A percentile p-value read off the
    resamples was not taken: it cannot go below 1/(B + 1), and Holm over a large family
    (t5_ratio_decreasing: 72 cells, α/72 = 1.4e-4 < 1/1001) could then never reject a slope.
    """
    from scipy.stats import t as student_t

    from sern_jax.analysis import stats

    n = int(np.asarray(data).shape[0])
    est, lo, hi = stats.bootstrap_ci(data, fn, seed=seed, num_resamples=num_resamples,
                                     level=1.0 - alpha, side="two", method="bca")
    side = "lower" if direction == "le" else "upper"
    _, lo1, hi1 = stats.bootstrap_ci(data, fn, seed=seed, num_resamples=num_resamples,
                                     level=1.0 - alpha, side=side, method="bca")
    se = max((hi - lo) / (2.0 * float(student_t.ppf(1.0 - alpha / 2.0, n - 1))), 1e-300)
    p = stats.t_pvalue(est, se, n, float(bound), direction)
    lower, upper = (lo1, hi) if direction == "le" else (lo, hi1)
    exc = stats.t_detectable_excess(se, n, alpha)
    det = float(bound) + exc if direction == "le" else float(bound) - exc
    return Cell(label, est, float(bound), direction, lower=lower, upper=upper, pvalue=p,
                detectable=det, n=n, se=se, **kw)


# ---------------------------------------------------------------------------------------
# Verdicts
# ---------------------------------------------------------------------------------------


def decide(cells: list[Cell], alpha: float) -> str:
    """Holm over the statistical cells; exact cells fail on any violation. Sets each cell's
    verdict and returns the family verdict."""
    from sern_jax.analysis import stats

    tested = [c for c in cells if not c.info_only]
    stat_cells = [c for c in tested if not c.exact]
    if stat_cells:
        reject, _ = stats.holm([c.pvalue for c in stat_cells], alpha)
        for c, r in zip(stat_cells, reject):
            c.violated = bool(r)
    for c in cells:
        if c.info_only and not c.exact and not math.isnan(c.pvalue):
            c.violated = c.pvalue <= alpha
        if c.violated:
            c.verdict = FAIL
        elif c.vacuous:
            c.verdict = VACUOUS
        elif not c.informative:
            c.verdict = UNINFORMATIVE
        else:
            c.verdict = PASS
    if any(c.verdict == FAIL for c in tested):
        return FAIL
    if any(c.verdict == PASS for c in tested):
        return PASS
    if tested and all(c.verdict == VACUOUS for c in tested):
        return VACUOUS
    return UNINFORMATIVE


def headline_cell(cells: list[Cell]) -> Cell:
    tested = [c for c in cells if not c.info_only] or cells
    failing = [c for c in tested if c.verdict == FAIL]
    pool = failing or tested
    return min(pool, key=lambda c: c.slack())


def fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if isinstance(x, float) and math.isinf(x):
        return "∞" if x > 0 else "−∞"
    ax = abs(x)
    if ax != 0 and (ax >= 1e5 or ax < 1e-3):
        return f"{x:.3g}"
    return f"{x:.4g}"


def describe(cell: Cell) -> str:
    op = {"le": "≤", "ge": "≥", "eq": "="}[cell.direction]
    ci = "" if cell.exact else f" [{fmt(cell.lower)}, {fmt(cell.upper)}]"
    return f"{cell.label}: {fmt(cell.statistic)}{ci} {op} {fmt(cell.bound)}"


def _power_str(c: Cell) -> str:
    if c.direction == "eq":
        return f"|statistic − {fmt(c.bound)}| ≥ {fmt(c.detectable)} ({c.label})"
    op = "≥" if c.direction == "le" else "≤"
    return f"statistic {op} {fmt(c.detectable)} vs bound {fmt(c.bound)} ({c.label})"


def finish(check: Check, ctx: Context, cells: list[Cell], *, seeds: int, power: str = "",
           notes: str = "", figure_data: dict | None = None, headline: str | None = None,
           by_construction: str | None = None) -> CheckResult:
    verdict = decide(cells, ctx.alpha)
    tested = [c for c in cells if not c.info_only]
    h = headline if headline is not None else (describe(headline_cell(cells)) if cells else "")
    if not power:
        det = [c for c in tested if not c.exact and not math.isnan(c.detectable)
               and c.informative and not c.vacuous]
        if det:
            rel = lambda c: abs(c.detectable - c.bound) / max(abs(c.bound), 1e-300)
            best, worst = min(det, key=rel), max(det, key=rel)
            power = (f"smallest violation detectable with 80% power (one-sided "
                     f"{1 - ctx.alpha:.0%} per cell): {_power_str(best)} at best; "
                     f"{_power_str(worst)} at worst")
        elif tested and all(c.exact for c in tested):
            power = "exact computation: any violation beyond 1e-9 relative is detected"
    return CheckResult(
        name=check.name, claim=check.claim, configuration=check.configuration,
        statistic=check.statistic, bound=check.bound, expected=check.expected,
        verdict=verdict, cells=cells, headline=h, power=power,
        by_construction=by_construction if by_construction is not None else check.by_construction,
        family_size=len(tested), seeds=seeds, mutated=ctx.mutate,
        mutation=check.mutation, notes=notes, figure_data=figure_data or {},
    )


# ---------------------------------------------------------------------------------------
# Cached engine runs (shared between checks) and cached simulations
# ---------------------------------------------------------------------------------------

_RUN_CACHE: dict = {}
_SIM_CACHE: dict = {}


def engine_run(*, estimator: str, means, horizon: int, num_seeds: int, alpha0: float,
               policy: str = "softmax", schedule: str = "constant", p: float = 0.3,
               num_checkpoints: int = 16, diagnostics: bool = False, clip: bool = True,
               seed: int = 0, context_probs=None, **oracle):
    """Runs the engine in float64 (cached by all arguments) and returns a numpy RunOutput.

    ``means`` is [K] (K-armed) or [M, K] (contexts). ``oracle`` holds beta / oracle_eps /
    flip_q / pinned_arm / epsilon overrides.
    """
    import jax

    from sern_jax.engine import drive as executor, simulate
    from sern_jax.core import problems

    m = np.asarray(means, dtype=np.float64)
    key = (estimator, m.tobytes(), m.shape, horizon, num_seeds, float(alpha0), policy, schedule,
           float(p), num_checkpoints, diagnostics, clip, seed,
           None if context_probs is None else tuple(context_probs),
           tuple(sorted((k, float(v)) for k, v in oracle.items())))
    if key in _RUN_CACHE:
        return _RUN_CACHE[key]
    with jax.enable_x64(True):
        if m.ndim == 1:
            prob = problems.bernoulli(m, dtype=jax.numpy.float64)
        else:
            prob = problems.contextual(m, context_probs, dtype=jax.numpy.float64)
        cfg = simulate.RunConfig(policy=policy, estimator=estimator, schedule=schedule,
                                 num_arms=m.shape[-1], num_contexts=1 if m.ndim == 1 else m.shape[0],
                                 horizon=int(horizon), num_checkpoints=num_checkpoints,
                                 clip=clip, dtype="float64", diagnostics=diagnostics)
        params = simulate.default_params(cfg, prob, alpha0=alpha0, p=p, **oracle)
        out = executor.run_seeds(cfg, params, seed=seed, num_seeds=num_seeds)
        out = jax.tree.map(np.asarray, out)
        times = simulate.checkpoint_times(cfg)
    res = (out, times)
    _RUN_CACHE[key] = res
    return res


def cached_simulate(check: Check, ctx: Context) -> dict:
    key = (check.name, ctx.quick, ctx.seeds, ctx.root_seed)
    if key not in _SIM_CACHE:
        _SIM_CACHE[key] = check.simulate(ctx)
    return _SIM_CACHE[key]


def run_check(check: Check, ctx: Context) -> CheckResult:
    t0 = time.perf_counter()
    data = cached_simulate(check, ctx)
    res = check.evaluate(data, ctx)
    res.wall_s = time.perf_counter() - t0
    return res


def alpha_log(alpha0: float, p: float, horizon: float) -> float:
    """alpha = alpha0 / ln(T^p) (Algorithm 1 / Theorem 4 schedule): ``schedules.alpha_of_horizon``
    with ``kind="log"``, as a float."""
    from sern_jax.core import schedules

    return float(schedules.alpha_of_horizon("log", horizon, alpha0, p))

