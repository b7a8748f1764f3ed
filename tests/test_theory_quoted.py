"""docs/THEORY.md's table of the full `sern check` run, and the intervals its theorem sections
quote, are those of the committed JSON report (experiments/results/theory/check_full.json);
its mean and equality cells are Student-t intervals (n − 1 dof) over seeds."""

import json
import math
from pathlib import Path

import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "experiments" / "results" / "theory" / "check_full.json"
NEURAL = {"n1_neural_floor", "a3_neural_error", "t4_neural_bound", "t3_neural_inequality",
          "alg1_neural_argmax"}  # the neural section's own table and files


@pytest.fixture(scope="module")
def doc():
    return json.loads(REPORT.read_text())


def _text():
    return " ".join((ROOT / "docs" / "THEORY.md").read_text().split())


def _check(doc, name):
    (c,) = [c for c in doc["checks"] if c["name"] == name]
    return c


def _cell(doc, name, label):
    (c,) = [c for c in _check(doc, name)["cells"] if c["label"] == label]
    return c


def _ends(cell):
    """A mean or equality cell's stored interval, checked to be Student t (n − 1 dof) from its
    n and se: the tested end one-sided 99%, the other end two-sided 99% (both ends two-sided
    for an equality cell)."""
    m, se, df = cell["statistic"], cell["se"], cell["n"] - 1
    one, two = stats.t.ppf(0.99, df) * se, stats.t.ppf(0.995, df) * se
    want = {"le": (m - one, m + two), "ge": (m - two, m + one), "eq": (m - two, m + two)}
    lo, hi = want[cell["direction"]]
    assert cell["lower"] == pytest.approx(lo, rel=1e-12, abs=1e-12), cell["label"]
    assert cell["upper"] == pytest.approx(hi, rel=1e-12, abs=1e-12), cell["label"]
    return cell["lower"], cell["upper"]


def test_the_report_is_a_full_run_with_every_verdict_as_expected(doc):
    opts = doc["options"]
    assert not opts["quick"] and not opts["wrong_bounds"] and opts["seeds"] is None
    assert opts["only"] in (None, []) and opts["alpha"] == 0.01
    assert doc["all_as_expected"]
    assert doc["metadata"]["versions"]["jax"] == "0.10.2"
    # every statistical mean cell is Student t: its two-sided end is t_{0.995, n-1}·se away
    mean_cells = [c for ch in doc["checks"] for c in ch["cells"] if c.get("n", 0) >= 2
                  and c["se"] > 0 and "zero-variance" not in c["note"]]
    assert len(mean_cells) > 100
    for c in mean_cells:
        _ends(c)


def test_table_rows_are_the_reports(doc):
    lines = (ROOT / "docs" / "THEORY.md").read_text().splitlines()
    start = lines.index("| check | expected | verdict (full run) | worst cell: statistic [99% CI] "
                        "vs bound | wall s |")
    rows = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        name = line.split(" | ")[0].strip("| `")
        rows[name] = line
    names = [c["name"] for c in doc["checks"] if c["name"] not in NEURAL]
    assert sorted(rows) == sorted(names)
    for name in names:
        c = _check(doc, name)
        assert rows[name] == (f"| `{name}` | {c['expected']} | {c['verdict']} | {c['headline']} "
                              f"| {round(c['wall_s'])} |"), name


def test_section_intervals_are_the_reports(doc):
    text = _text()
    quoted = []
    k2 = _cell(doc, "t1_tightness_pinned", "K=2 α=0.3: E N_a(T)/(cT)")
    lo, hi = _ends(k2)
    quoted.append(f"{k2['statistic']:.4f} [{lo:.4f}, {hi:.4f}] vs {k2['bound']:.4f} for K = 2, "
                  f"α = 0.3")
    k2a1 = _cell(doc, "t1_tightness_pinned", "K=2 α=1: E N_a(T)/(cT)")
    quoted.append(f"{k2a1['statistic']:.4f} vs {k2a1['bound']:.4f} for K = 2, α = 1")
    clip = _cell(doc, "t1_needs_clip", "t=113: E N_2(t)")
    lo, hi = _ends(clip)
    quoted.append(f"{clip['statistic']:.2f} [{lo:.2f}, {hi:.2f}] vs {clip['bound']:.2f} at "
                  f"t = 113, with {clip['n']} seeds")
    for r in ("(0.9, 0.5)", "(0.6, 0.4)"):
        c = _cell(doc, "a3_adaptive_addhalf", f"r={r}: E[Σ|err_a*| − β Σ(N_a*+1)^(−1/2)]")
        lo, hi = _ends(c)
        quoted.append(f"**{c['statistic']:.1f} [{lo:.1f}, {hi:.1f}]** for r = {r}"
                      if r == "(0.9, 0.5)" else f"**{c['statistic']:.1f} [{lo:.1f}, {hi:.1f}]**")
    sup = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
    for a0, T in ((10, 10_000), (10, 100_000), (1, 1_000_000)):
        lab = f"α0={a0} p=0.02 T={T}: "
        rb = _cell(doc, "t4_term3_flip", lab + "Σ_t P(misid) (RB)")
        floor = _cell(doc, "t4_term3_flip", lab + "analytic floor 2q_c(√(T+1)−1)")
        lo, hi = _ends(rb)
        quoted.append(f"| ({a0}, 0.02) | 10{str(int(math.log10(T))).translate(sup)} | "
                      f"{rb['statistic']:.1f} [{lo:.1f}, {hi:.1f}] | {floor['statistic']:.1f} | "
                      f"{rb['bound']:.1f} |")
    for q in quoted:
        assert q in text, q
