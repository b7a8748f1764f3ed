"""The figures docs/THEORY.md quotes for the neural checks (t3_neural_inequality,
alg1_neural_argmax, t4_neural_bound) are those of the committed JSON reports of `sern check`
runs (experiments/results/theory_neural/check_*.json), whose mean cells are Student-t
intervals over seeds (n − 1 dof); check_t3_alpha05_superseded_full.json, the superseded
α = 0.5 version of t3, predates that and holds normal (z) intervals."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "experiments" / "results" / "theory_neural" / "check_t3_alg1_full.json"
SUPERSEDED = REPORT.parent / "check_t3_alpha05_superseded_full.json"


def _cells(doc, name):
    (check,) = [c for c in doc["checks"] if c["name"] == name]
    return check


def _num(note, label):
    return float(re.search(re.escape(label) + r" ([-\d.]+)", note).group(1))


def _t99(cell, n):
    """The two-sided Student t 99% interval (n − 1 dof) of a framework.mean_cell 'le' cell,
    from its n and se; the report's stored two-sided (upper) end must be that interval's."""
    from scipy import stats

    assert cell["n"] == n and cell["direction"] == "le"
    h = stats.t.ppf(0.995, n - 1) * cell["se"]
    assert cell["upper"] == pytest.approx(cell["statistic"] + h, rel=1e-12)
    return cell["statistic"] - h, cell["statistic"] + h


def _t99_from_z(cell, n):
    """Student t 99% (n − 1 dof) from a cell of the earlier normal-theory framework (no n, se
    stored): its mean and two-sided z upper end give se = (upper − mean)/z_0.995."""
    from scipy import stats

    assert "se" not in cell
    se = (cell["upper"] - cell["statistic"]) / stats.norm.ppf(0.995)
    h = stats.t.ppf(0.995, n - 1) * se
    return cell["statistic"] - h, cell["statistic"] + h


def _m(x, fmt):
    return format(x, fmt).replace("-", "−")


def _text():
    return " ".join((ROOT / "docs" / "THEORY.md").read_text().split())


def _load(name):
    return json.loads((REPORT.parent / name).read_text())


def test_t3_figures_match_the_reports():
    text = _text()
    full, mut = _load("check_t3_full.json"), _load("check_t3_mutated_full.json")
    quick, mutq = _load("check_t3_alg1_quick.json"), _load("check_t3_mutated_quick.json")
    assert full["all_as_expected"] and not full["options"]["quick"]
    assert not full["options"]["wrong_bounds"] and mut["options"]["wrong_bounds"]
    assert quick["options"]["quick"] and mutq["options"]["quick"] and mutq["options"]["wrong_bounds"]
    t3 = _cells(full, "t3_neural_inequality")
    assert t3["verdict"] == "PASS" and t3["seeds"] == 64
    paper, pathwise, ingredient = t3["cells"]
    assert paper["vacuous"] and not pathwise["vacuous"]
    n, pn = paper["note"], pathwise["note"]
    bound, trivial = _num(n, "vs bound"), _num(n, "Δ_max·T =")
    assert bound >= trivial  # VACUOUS: the mean bound reaches Δ_max·T
    assert "α=0.1" in paper["label"]
    # α ln K at α = 0.5 exceeds both gaps; at α = 0.1 it is below them
    g, dmax = _num(pn, "(g"), _num(n, "(Δ_max")
    assert 0.5 * math.log(3) > g > dmax > 0.1 * math.log(3)
    lo, hi = _t99(paper, 64)
    ilo, ihi = _t99(ingredient, 64)
    qi = _cells(quick, "t3_neural_inequality")["cells"][2]
    qlo, qhi = _t99(qi, 32)
    m_path = _cells(mut, "t3_neural_inequality")["cells"][1]["statistic"]
    mq_path = _cells(mutq, "t3_neural_inequality")["cells"][1]["statistic"]
    assert _cells(mut, "t3_neural_inequality")["verdict"] == "FAIL"
    assert _cells(mutq, "t3_neural_inequality")["verdict"] == "FAIL"
    assert mq_path < 0  # the quick-size control fails too
    old = _cells(json.loads(SUPERSEDED.read_text()), "t3_neural_inequality")
    assert "α=0.5" in old["cells"][0]["label"]
    # the regenerated t3 + alg1 full report holds today's α = 0.1 t3, equal to check_t3_full's
    t3_again = _cells(json.loads(REPORT.read_text()), "t3_neural_inequality")
    assert [c["statistic"] for c in t3_again["cells"]] == [c["statistic"] for c in t3["cells"]]
    quoted = [
        f"min (rhs − R_t)/rhs = {pathwise['statistic']:.3f} ≥ 0, rhs below the trivial g·t on "
        f"{_num(pn, 'on'):.1f}% of seed-checkpoints; paper's form VACUOUS (mean bound "
        f"{bound:.1f} ≥ Δ_max·T = {trivial:.1f}) |",
        f"span Δ_max = {dmax:.3f}", f"Δ_max·T = {trivial:.1f}, and the largest per-context gap "
        f"is g = {g:.3f}",
        f"α ln K = {0.5 * math.log(3):.3f} per round", f"α ln K = {0.1 * math.log(3):.3f}.",
        f"is {pathwise['statistic']:.3f} (mean R_T {_num(pn, 'R_T(per-context)'):.1f} against "
        f"{_num(pn, 'vs rhs'):.1f}), with the right-hand side below g·t on "
        f"{_num(pn, 'on'):.1f}% of the seed-checkpoints",
        f"the smallest margin is {_m(m_path, '.3f')} (FAIL",
        f"(β = {_num(n, 'β ='):.3f}): mean R_T {_m(_num(n, 'R_T'), '.1f')}",
        f"mean bound of {bound:.1f} (β Σ(N_{{a*}}+1)^{{−1/2}} {_num(n, '^-½'):.1f}, "
        f"β Σ(N_{{a_t}}+1)^{{−1/2}} {_num(n, 'β Σ(N_at+1)^-½'):.1f}, Σ 1{{â* ≠ a*}} "
        f"{_num(n, 'Σ 1{â*≠a*}'):.1f}, α ln K·T {_num(n, 'α ln K·T'):.1f}), which exceeds "
        f"Δ_max·T = {trivial:.1f}",
        f"difference {_m(paper['statistic'], '.0f')} [{_m(lo, '.0f')}, {_m(hi, '.0f')}], "
        f"Student t 99% over 64 seeds",
        f"the bound is {_num(n, 'α ln K·T'):.1f} and R_T still lies below it",
        f"= {_num(ingredient['note'], 'ratio'):.3f}, difference "
        f"{_m(ingredient['statistic'], '.1f')} [{_m(ilo, '.1f')}, {_m(ihi, '.1f')}]",
        f"quick size {_num(qi['note'], 'ratio'):.3f}, {_m(qi['statistic'], '.1f')} "
        f"[{_m(qlo, '.1f')}, {_m(qhi, '.1f')}] (32 seeds)",
    ]
    # the superseded α = 0.5 figures, from check_t3_alg1_full.json (t interval: contains 0)
    oi = old["cells"][2]
    olo, ohi = _t99_from_z(oi, 64)
    assert olo < 0 < ohi
    quoted.append(f"gave {_num(oi['note'], 'ratio'):.3f}, +{oi['statistic']:.1f} "
                  f"[{_m(olo, '.2f')}, {ohi:.2f}] (full; its quick-size run was not kept)")
    for q in quoted:
        assert q in text, q


def test_alg1_figures_match_the_reports():
    text = _text()
    doc, quick = json.loads(REPORT.read_text()), _load("check_t3_alg1_quick.json")
    assert not doc["options"].get("quick")
    al = _cells(doc, "alg1_neural_argmax")
    assert al["verdict"] == "FAIL" and al["expected"] == "FAILS" and al["seeds"] == 64
    printed, control = al["cells"]
    early, late = re.search(r"R/t = ([\d.]+) → ([\d.]+)", printed["note"]).groups()
    c_late = re.search(r"→ ([\d.]+)", control["note"]).group(1)
    lo, hi = _t99(printed, 64)
    qa = _cells(quick, "alg1_neural_argmax")
    assert qa["verdict"] == "FAIL" and qa["seeds"] == 32
    qp = qa["cells"][0]
    qlo, qhi = _t99(qp, 32)
    q_early, q_late = re.search(r"R/t = ([\d.]+) → ([\d.]+)", qp["note"]).groups()
    from proofs_check import neural_runs

    uniform = np.mean([max(r) - np.mean(r) for r in neural_runs.SPLIT_MEANS])
    quoted = [f"at t = 2000 − at t = 20 = {printed['statistic']:.3f} [{lo:.3f}, {hi:.3f}] vs ≤ 0 "
              f"(Student t 99%, 63 dof)",
              f"α0 = α·p·ln T = {0.1 * 0.3 * math.log(2000):.2f}",
              f"from {float(early):.3f} at t = 20", f"to {float(late):.3f} at t = 2000",
              f"uniform play's {uniform:.3f}",
              f"increase {printed['statistic']:.3f} [{lo:.3f}, {hi:.3f}] (Student t 99%, 64 "
              f"seeds)",
              f"goes from {float(early):.3f} to {float(c_late):.3f}",
              f"{q_early} → {q_late}, increase {qp['statistic']:.3f} [{qlo:.3f}, {qhi:.3f}]"]
    for q in quoted:
        assert q in text, q


def test_t4_quick_figures_match_the_report():
    doc = _load("check_t4_quick.json")
    text = _text()
    assert doc["options"]["quick"] and doc["all_as_expected"]
    t4 = _cells(doc, "t4_neural_bound")
    assert t4["verdict"] == "VACUOUS" and t4["seeds"] == 32
    learned, frozen = t4["cells"]
    mant, exp = f"{learned['bound']:.1e}".split("e+")
    sup = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
    quoted = [f"mean R_T = {learned['statistic']:.1f} (paper's pseudo-regret, scaled rewards) "
              f"against B(T) = {mant}·10{str(int(exp)).translate(sup)}, VACUOUS; fitted β = "
              f"{_num(learned['note'], 'β_s ='):.3f} and log10 T* = "
              f"{_num(learned['note'], 'log10 T* ='):.1f}",
              f"has β = {_num(frozen['note'], 'β_s ='):.2f} and log10 T* = "
              f"{_num(frozen['note'], 'log10 T* ='):.1f}"]
    for q in quoted:
        assert q in text, q


def test_t4_full_size_figures_match_the_report():
    doc = json.loads((REPORT.parent / "check_t4_full.json").read_text())
    text = " ".join((ROOT / "docs" / "THEORY.md").read_text().split())
    assert doc["all_as_expected"] and not doc["options"].get("quick")
    t4 = _cells(doc, "t4_neural_bound")
    assert t4["verdict"] == "VACUOUS" and t4["seeds"] == 64
    learned, frozen = t4["cells"]
    from scipy import stats

    # Student t over the 64 seeds: one-sided 99% lower end, two-sided 99% upper end
    assert learned["n"] == 64
    assert learned["lower"] == pytest.approx(
        learned["statistic"] - stats.t.ppf(0.99, 63) * learned["se"], rel=1e-12)
    assert learned["upper"] == pytest.approx(
        learned["statistic"] + stats.t.ppf(0.995, 63) * learned["se"], rel=1e-12)
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


def test_n1_a3_figures_match_the_report():
    doc = _load("check_n1_a3_full.json")
    text = _text()
    assert doc["all_as_expected"] and not doc["options"]["quick"]
    n1 = _cells(doc, "n1_neural_floor")
    assert n1["verdict"] == "PASS" and n1["seeds"] == 64
    floor = {c["label"]: c["statistic"] for c in n1["cells"]}
    worst = min((v, k) for k, v in floor.items() if k.startswith("sern"))
    assert worst[1] == "sern α=0.5 K=3: min π_t(a)/c"
    assert all(v >= 1 for k, v in floor.items() if k.startswith("sern"))
    a3 = _cells(doc, "a3_neural_error")
    assert a3["verdict"] == "FAIL" and a3["expected"] == "FAILS" and a3["seeds"] == 64
    learned = [c for c in a3["cells"] if not c["label"].startswith("control")]
    frozen = [c for c in a3["cells"] if c["label"].startswith("control")]
    assert all(c["lower"] > -0.5 for c in learned)  # each rejects slope ≤ −1/2
    c0 = learned[0]
    betas = [_num(c["note"], "E n+1) =") for c in learned]
    fbetas = [_num(c["note"], "β_s =") for c in frozen]
    quoted = [f"min π_t(a)/c = {worst[0]:.3f} ≥ 1",
              f"context 0: slope {_m(c0['statistic'], '.3f')} [99% BCa {_m(c0['lower'], '.3f')}, "
              f"{_m(c0['upper'], '.3f')}] vs ≤ −0.5",
              "is " + ", ".join(_m(c["statistic"], ".2f") for c in learned) + " (four contexts)",
              f"is {min(betas):.2f}–{max(betas):.2f}, but",
              f"β_s {min(fbetas):.1f}–{max(fbetas):.1f} growing"]
    for q in quoted:
        assert q in text, q
