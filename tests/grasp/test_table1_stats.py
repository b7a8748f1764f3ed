"""Table I's spread statistics: table.json rows carry sd (ddof 1) and se beside the old std
(ddof 0), and the paper's parenthesised values are standard errors."""

import math

import numpy as np
import pytest

from experiments import paper_table1
from sern_jax.grasp.online import checkpoint


def test_table_rows_carry_sd_and_se_beside_std():
    rng = np.random.default_rng(0)
    paper = rng.integers(0, 6, (3, 1, 1, 5)) / 5.0  # [R+1, O, Q, S]: 5-grasp rates
    row = checkpoint.table_rows(["obj"], ("sern",), paper)[0]
    x = 100.0 * paper[1:, 0, 0, :]
    np.testing.assert_allclose(row["std"], x.std(1))  # unchanged contract (ddof 0)
    np.testing.assert_allclose(row["sd"], x.std(1, ddof=1))
    np.testing.assert_allclose(row["se"], x.std(1, ddof=1) / math.sqrt(5))
    one = checkpoint.table_rows(["obj"], ("sern",), paper[..., :1])[0]
    assert one["sd"] == [None, None] and one["se"] == [None, None]


def test_possible_values_by_hand():
    # five seeds, one success more on one seed: rates (0, 0, 0, 0, 20) %:
    # mean 4, population SD sqrt(400 * 4/25) = 8, sample SD sqrt(80) = 8.94, SE 4.00
    rows = paper_table1.possible_values()
    assert len(rows) == math.comb(6 + 5 - 1, 5)  # 252 multisets
    r = next(r for r in rows if r["mean"] == 4.0)
    assert r["sd_pop"] == pytest.approx(8.0)
    assert r["sd_sample"] == pytest.approx(math.sqrt(80))
    assert r["se_sample"] == pytest.approx(4.0)
