"""docs/THEORY.md's a3_neural_error figures after the BCa cells' p-values became Student t
(context 0: p 8.9·10⁻⁵, detectable slope −0.2625) are those of the committed
experiments/results/theory_neural/check_n1_a3_full.json, recomputed from each cell's n and se:
the report's stored p-value and detectable slope are Student t with n − 1 dof on the se its
two-sided 99% BCa interval implies (proofs_check.framework.bootstrap_cell)."""

import json
import re
from pathlib import Path

import pytest
from scipy import stats as sps

from sern_jax.analysis import stats

ROOT = Path(__file__).resolve().parents[1]
REPORT = ROOT / "experiments" / "results" / "theory_neural" / "check_n1_a3_full.json"
ALPHA = 0.01

_SUP = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")


def _sci(p: float) -> str:
    """8.900917e-05 -> '8.9·10⁻⁵' (THEORY's notation)."""
    mantissa, exp = f"{p:.1e}".split("e")
    return f"{mantissa}·10⁻{str(-int(exp)).translate(_SUP)}"


def test_a3_pvalue_and_detectable_slope_recomputed_from_the_report():
    doc = json.loads(REPORT.read_text())
    (a3,) = [c for c in doc["checks"] if c["name"] == "a3_neural_error"]
    assert a3["seeds"] == 64 and doc["options"]["alpha"] == ALPHA
    learned = [c for c in a3["cells"] if not c["label"].startswith("control")]
    c0 = learned[0]
    assert c0["label"].startswith("context 0:") and c0["direction"] == "le"
    for c in a3["cells"]:
        n, se = c["n"], c["se"]
        assert n == 64 and se > 0, c  # bootstrap_cell records them (n 0, se nan before)
        # se: the two-sided 99% BCa interval's half-width over t_{0.995, n-1}
        t = (c["statistic"] - c["bound"]) / se
        assert c["pvalue"] == pytest.approx(sps.t.sf(t, n - 1), rel=1e-9), c["label"]
        assert c["detectable"] == pytest.approx(
            c["bound"] + stats.t_detectable_excess(se, n, ALPHA), rel=1e-9), c["label"]
    p, det = c0["pvalue"], c0["detectable"]
    assert _sci(p) == "8.9·10⁻⁵"
    text = " ".join((ROOT / "docs" / "THEORY.md").read_text().split())
    assert f"p 5.6·10⁻⁵ → {_sci(p)}" in text
    assert f"detectable slope −0.2604 → −{abs(det):.4f}" in text
    # the report's power line is the same figure, the worst of the four contexts
    assert f"statistic ≥ {det:.4f} vs bound -0.5 (context 0" in a3["power"]
    assert det == max(c["detectable"] for c in learned)
    assert re.search(r"−0\.2625\b", text)
