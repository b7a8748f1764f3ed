"""`sern reproduce`'s report prints Table I as docs/RESULTS.md does: SE in parentheses,
labelled, and the fixed-pose evaluation by that name."""

from sern_jax.commands import reproduce


def test_table_prints_the_standard_error_and_says_so():
    rows = [{"object": "o", "policy": "sern", "theta0": 50.0, "rounds": [40.0, 80.0],
             "std": [4.0, 8.0], "sd": [4.47, 8.94], "se": [2.0, 4.0], "max": 80.0,
             "imprv": 1.0, "lowvar_rounds": [30.0, 45.0, 85.0], "lowvar_std": [1.0, 2.0, 3.0]}]
    md = reproduce._table_markdown(rows)
    assert "| o | sern | 50 % | 40 % (SE 2.00) | 80 % (SE 4.00) | 80 % | 100 % |" in md
    assert "standard error over the seeds" in md and "ddof 1" in md
    assert "Fixed-pose evaluation" in md and "low-variance" not in md.lower()
    assert "| o | sern | 30 % | 45 % | 85 % |" in md
    one_seed = [dict(rows[0], se=[None, None])]
    assert "| 40 % | 80 % |" in reproduce._table_markdown(one_seed)


def test_paired_lines_print_the_t_half_width_and_say_so(tmp_path):
    import json

    import numpy as np

    from sern_jax.analysis import stats
    from sern_jax.infra import io

    rng = np.random.default_rng(0)
    lowvar = rng.random((3, 2, 3, 6))  # [round, object, policy, seed]
    paper = rng.random((3, 2, 3, 6))
    io.save_npz(tmp_path / "results.npz", lowvar_eval=lowvar, paper_eval=paper)
    (tmp_path / "config.json").write_text(json.dumps(
        {"config": {"policies": ["sern", "egreedy", "greedy"]}}))
    lines = reproduce._paired_lines(tmp_path)
    assert "± is the 95 % Student-t half-width" in lines[0] and "Holm over the 4" in lines[0]
    pooled = lowvar[-1].mean(0)
    want = stats.paired_differences(100 * (pooled[0] - pooled[2]))[0]
    assert f"SERN − greedy, fixed-pose evaluation: {want.mean:+.1f} ± {want.half:.1f}" in \
        "\n".join(lines)
