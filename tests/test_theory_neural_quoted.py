"""The figures docs/THEORY.md quotes for t3_neural_inequality and alg1_neural_argmax are those
of the committed JSON report of the full-size `sern check` run
(experiments/results/theory_neural/check_t3_alg1_full.json)."""

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "experiments" / "results" / "theory_neural" / "check_t3_alg1_full.json"


def _cells(doc, name):
    (check,) = [c for c in doc["checks"] if c["name"] == name]
    return check


def _num(note, label):
    return float(re.search(re.escape(label) + r" ([-\d.]+)", note).group(1))


def test_quoted_figures_match_the_report():
    doc = json.loads(REPORT.read_text())
    text = " ".join((ROOT / "docs" / "THEORY.md").read_text().split())
    assert doc["all_as_expected"] and not doc["options"].get("quick")
    t3 = _cells(doc, "t3_neural_inequality")
    assert t3["verdict"] == "PASS" and t3["seeds"] == 64
    paper, pathwise, ingredient = t3["cells"]
    n = paper["note"]
    quoted = [f"mean R_T {_num(n, 'R_T'):.1f} (paper's regret) against a bound of "
              f"{_num(n, 'vs bound'):.0f}",
              f"β = {_num(n, 'β ='):.3f}",
              f"β Σ(N_{{a*}}+1)^{{−1/2}} {_num(n, '^-½'):.1f}",
              "per-seed difference " + f"{paper['statistic']:.0f} [{paper['lower']:.0f}, "
              f"{paper['upper']:.0f}]".replace("-", "−"),
              f"{pathwise['statistic']:.3f} (mean R_T {_num(pathwise['note'], 'R_T(per-context)'):.1f} "
              f"against {_num(pathwise['note'], 'vs rhs'):.0f})",
              f"= {_num(ingredient['note'], 'ratio'):.3f}, the difference "
              f"{ingredient['statistic']:.1f} [{ingredient['lower']:.2f}, {ingredient['upper']:.1f}]",
              f"({100 * _num(ingredient['note'], 'â* ≠ a*:'):.1f}% of the rounds)"]
    al = _cells(doc, "alg1_neural_argmax")
    assert al["verdict"] == "FAIL" and al["expected"] == "FAILS"
    printed, control = al["cells"]
    early, late = re.search(r"R/t = ([\d.]+) → ([\d.]+)", printed["note"]).groups()
    c_late = re.search(r"→ ([\d.]+)", control["note"]).group(1)
    quoted += [f"from {float(early):.3f} at t = 20", f"to {float(late):.3f} at t = 2000",
               f"increase {printed['statistic']:.3f} [{printed['lower']:.3f}, "
               f"{printed['upper']:.3f}]",
               f"goes from {float(early):.3f} to {float(c_late):.3f}"]
    for q in quoted:
        assert q in text, q


def test_t4_full_size_figures_match_the_report():
    doc = json.loads((REPORT.parent / "check_t4_full.json").read_text())
    text = " ".join((ROOT / "docs" / "THEORY.md").read_text().split())
    assert doc["all_as_expected"] and not doc["options"].get("quick")
    t4 = _cells(doc, "t4_neural_bound")
    assert t4["verdict"] == "VACUOUS" and t4["seeds"] == 64
    learned, frozen = t4["cells"]
    mant, exp = f"{learned['bound']:.2e}".split("e+")
    sup = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
    quoted = [f"mean R_T {learned['statistic']:.1f} [{learned['lower']:.1f}, "
              f"{learned['upper']:.1f}]",
              f"B(T) = {mant}·10{str(int(exp)).translate(sup)}, log10 T* = "
              f"{_num(learned['note'], 'log10 T* ='):.1f} |",
              f"mean R_T = {learned['statistic']:.1f} against B(T) = {mant}·10"
              f"{str(int(exp)).translate(sup)}, VACUOUS; fitted β = "
              f"{_num(learned['note'], 'β_s ='):.3f}, log10 T* = "
              f"{_num(learned['note'], 'log10 T* ='):.1f}; frozen at θ0: β = "
              f"{_num(frozen['note'], 'β_s ='):.3f}, log10 T* = "
              f"{_num(frozen['note'], 'log10 T* ='):.1f}"]
    for q in quoted:
        assert q in text, q
