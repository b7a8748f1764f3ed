"""The one generated-numbers test: every marked block of README.md and docs/*.md equals what
figures/doc_tables.py builds from the records under experiments/results/, and the
comparison fails on a page whose number was edited by hand."""

import re

import pytest

from figures import doc_tables as dt


def test_every_block_on_the_pages_is_what_the_records_give():
    bad = dt.stale()
    assert bad == [], ("blocks differ from the records; run `python -m figures.doc_tables`: "
                       + ", ".join(bad))


def test_every_block_is_used_on_some_page():
    used = {m.group(2) for p in dt.pages() for m in dt.MARK.finditer(p.read_text())}
    assert set(dt.BLOCKS) - used == set()


def test_a_changed_number_fails(tmp_path):
    """Control: the same page with one digit of one generated block changed is stale."""
    page = dt.ROOT / "docs" / "RESULTS.md"
    text = page.read_text()
    m = next(m for m in dt.MARK.finditer(text) if m.group(2) == "results-strong-finding")
    body = m.group(3)
    digit = re.search(r"\d", body)
    changed = body[:digit.start()] + str((int(digit.group()) + 1) % 10) + body[digit.end():]
    bad = tmp_path / "RESULTS.md"
    bad.write_text(text[:m.start(3)] + changed + text[m.end(3):])
    assert dt.stale([bad]) == [f"{bad}: results-strong-finding"]
    good = tmp_path / "same.md"
    good.write_text(text)
    assert dt.stale([good]) == []


def test_fill_rewrites_only_marked_blocks_and_refuses_unknown_ones():
    text = "a\n<!-- doc-tables:x -->\nold\n<!-- /doc-tables:x -->\nb\n"
    assert dt.fill(text, lambda name: f"new {name}") == (
        "a\n<!-- doc-tables:x -->\nnew x\n<!-- /doc-tables:x -->\nb\n")
    with pytest.raises(KeyError, match="unknown"):
        dt.fill(text)
    with pytest.raises(KeyError, match="closing"):
        dt.fill("<!-- doc-tables:results-glance -->\nno end\n")


def test_formatting_conventions():
    assert dt.pts(0.013) == "+1.3" and dt.pts(-0.0001) == "+0.0"
    assert dt.interval(-0.002, 0.027) == "[−0.2, +2.7]"
    assert dt.pm(0.169, 0.015) == "+16.9 ± 1.5"
    assert dt.pval(0.4219) == "0.42" and dt.pval(0.0005) == "5e−4"
    assert "\\|" in dt.table(["a"], [["x|y"]])


def test_interval_kind_reads_the_cells_numbers():
    from scipy import stats as sps

    se, n, m = 0.1, 64, 1.0
    one, two = sps.t.ppf(0.99, n - 1) * se, sps.t.ppf(0.995, n - 1) * se
    cell = {"statistic": m, "lower": m - one, "upper": m + two, "n": n, "se": se, "note": ""}
    assert dt.interval_kind(cell) == "Student t 99 %: lower end one-sided, upper end two-sided"
    cell.update(lower=m - two)
    assert dt.interval_kind(cell) == "Student t 99 %, two-sided"
    cell.update(lower=m - 3 * two)  # neither t end: read as a bootstrap interval
    assert dt.interval_kind(cell) == "BCa bootstrap 99 %, two-sided"


def test_theory_slope_test_is_one_sided():
    """H0: slope ≤ −1/2. A run whose slope is steeper than −1/2 is not 'slower than the rate'
    however tight its interval; flatter slopes are."""
    s = dt._theory_grasping("theory_grasping_other_6N")["per_object"]
    assert s["triangular_prism"]["slope_mean"] < -0.5
    assert s["triangular_prism"]["one_sided_p"] > 0.5
    assert s["tless_part_b"]["slope_mean"] > -0.5 and s["tless_part_b"]["one_sided_p"] < 0.01
