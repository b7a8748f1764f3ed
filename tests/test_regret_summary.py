"""`sern regret --no-per-seed`: the run keeps on-device summaries over seeds, and its
summary.json equals the per-seed run's, up to float rounding; quantile brackets hold the exact
quantiles; an interrupted run resumes."""

import json

import numpy as np
import pytest

from sern_jax.engine import drive as executor
from sern_jax.infra import io
from sern_jax.commands import main as cli

ARGS = ["regret", "--policies", "softmax,greedy", "--arms", "4", "--horizon", "200",
        "--seeds", "70", "--chunk-size", "32", "--checkpoints", "8", "--no-progress",
        "--no-figures"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("regret_summary")
    assert cli.main(ARGS + ["--out", str(base / "per_seed")]) == 0
    assert cli.main(ARGS + ["--no-per-seed", "--out", str(base / "summary")]) == 0
    return base / "per_seed", base / "summary"


def test_summary_run_equals_per_seed_run(runs):
    per_seed, summ = (json.loads((d / "summary.json").read_text()) for d in runs)
    assert summ["per_seed"] is False and summ["num_seeds"] == 70
    res = io.load_npz(runs[0] / "results.npz")
    for policy in ("softmax", "greedy"):
        a, b = per_seed["policies"][policy], summ["policies"][policy]
        for key in ("regret_T_mean", "regret_T_realised_mean", "regret_paper_T_mean"):
            np.testing.assert_allclose(b[key], a[key], rtol=1e-6, err_msg=key)
        np.testing.assert_allclose(b["regret_T_ci95"], a["regret_T_ci95"], rtol=1e-5)
        assert b["min_prob"] == a["min_prob"]
        np.testing.assert_allclose(b["slope_last_decade"]["slope"],
                                   a["slope_last_decade"]["slope"], rtol=1e-5)
        final = res[f"{policy}__regret_rb"][:, -1]
        for q, got in b["regret_T_quantiles"].items():
            exact = float(np.quantile(final, float(q), method="inverted_cdf"))
            assert got["lo"] <= exact <= got["hi"], (policy, q)
    # the saved results are the summaries, not per-seed arrays: small whatever the seeds
    saved = executor.summary_from_arrays(io.load_npz(runs[1] / "results.npz"), "softmax__")
    assert saved.num_seeds == 70
    assert "softmax__regret_rb" not in io.load_npz(runs[1] / "results.npz")


def test_summary_run_resumes_and_refuses_the_per_seed_directory(runs, tmp_path, capsys):
    chunk_dir = runs[1] / "chunks"
    names = sorted(p.name for p in chunk_dir.glob("*.npz"))
    assert len(names) == 6 and all("__summary_" in n for n in names)  # 2 policies x 3 chunks
    before = (runs[1] / "summary.json").read_text()
    (chunk_dir / names[1]).unlink()  # an interrupted run
    assert cli.main(ARGS + ["--no-per-seed", "--out", str(runs[1])]) == 0
    assert (runs[1] / "summary.json").read_text() == before
    # a per-seed directory is another experiment
    assert cli.main(ARGS + ["--no-per-seed", "--out", str(runs[0])]) == 2
    assert "different experiment" in capsys.readouterr().err
