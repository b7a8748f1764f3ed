"""Tests for sern_jax.commands.grasp_learn (Table I rows and formatting, the learn outputs) and
sern_jax.commands.reproduce (its summary helpers, and an early clear error without θ0)."""

import argparse
import json

import numpy as np
import pytest

from sern_jax.infra import io
from sern_jax.commands import grasp_learn as learn_cli
from sern_jax.commands import reproduce
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import checkpoint
from sern_jax.grasp.online import config as online_config


def _paper_eval():
    """[R + 1 = 3, O = 1, Q = 2, S = 2] success fractions."""
    x = np.zeros((3, 1, 2, 2))
    x[:, 0, 0] = [[0.4, 0.6], [0.2, 0.4], [0.6, 0.6]]  # sern: θ0 50, rounds 30, 60
    x[:, 0, 1] = [[0.2, 0.2], [0.0, 0.0], [0.4, 0.2]]  # greedy: round 1 = 0
    return x


def test_table_rows_max_and_improvement():
    rows = checkpoint.table_rows(["box"], ("sern", "greedy"), _paper_eval())
    sern, greedy = rows
    assert sern["theta0"] == pytest.approx(50.0)
    assert sern["rounds"] == pytest.approx([30.0, 60.0])
    assert sern["std"] == pytest.approx([10.0, 0.0])
    assert sern["max"] == pytest.approx(60.0)
    assert sern["imprv"] == pytest.approx((60.0 - 30.0) / 30.0)  # (r_R - r_1) / r_1
    assert greedy["rounds"] == pytest.approx([0.0, 30.0])
    assert greedy["max"] == pytest.approx(30.0)
    assert greedy["imprv"] is None  # r_1 = 0: undefined
    assert "lowvar_rounds" not in sern
    lowvar = np.full((3, 1, 2, 2), 0.5)
    with_lv = checkpoint.table_rows(["box"], ("sern", "greedy"), _paper_eval(), lowvar)
    assert with_lv[0]["lowvar_rounds"] == pytest.approx([50.0] * 3)
    # a NaN low-variance array (evaluation off) leaves the columns out
    nan_lv = checkpoint.table_rows(["box"], ("sern", "greedy"), _paper_eval(), lowvar * np.nan)
    assert "lowvar_rounds" not in nan_lv[0]


def test_format_table():
    rows = checkpoint.table_rows(["box"], ("sern", "greedy"), _paper_eval())
    text = learn_cli.format_table(rows)
    lines = text.splitlines()
    assert lines[0] == "| Obj. | Alg. | θ0 | Round 1 | Round 2 | Max. | Imprv. |"
    assert lines[1] == "|---|---|---|---|---|---|---|"
    assert lines[2] == "| box | sern | 50% | 30% (±10.00) | 60% (±0.00) | 60% | 100% |"
    assert lines[3] == "| box | greedy | 20% | 0% (±0.00) | 30% (±10.00) | 30% | — |"
    assert len(lines) == 6 and lines[4] == ""
    assert "population standard deviation" in lines[5] and "`se`" in lines[5]
    # a decline is a negative improvement
    declining = [dict(rows[0], rounds=[80.0, 60.0], max=80.0, imprv=-0.25)]
    assert learn_cli.format_table(declining).splitlines()[2].endswith("| 80% | -25% |")


def test_format_table_with_lowvar():
    lowvar = np.zeros((3, 1, 2, 2))
    lowvar[:, 0, 0] = [[0.5, 0.7], [0.6, 0.6], [1.0, 0.8]]
    rows = checkpoint.table_rows(["box"], ("sern", "greedy"), _paper_eval(), lowvar)
    lines = learn_cli.format_table(rows).splitlines()
    i = lines.index("| Obj. | Alg. | R0 | R1 | R2 |")
    assert lines[i + 2] == "| box | sern | 60% (±10.0) | 60% (±0.0) | 90% (±10.0) |"
    assert lines[i + 3] == "| box | greedy | 0% (±0.0) | 0% (±0.0) | 0% (±0.0) |"


def test_write_learn_outputs(tmp_path, tiny_theta0):
    config = online_config.OnlineConfig(policies=("sern", "greedy"), num_seeds=2, rounds=2)
    pe = _paper_eval()
    results = checkpoint.RoundResults(pe, pe, pe, np.zeros(pe.shape + (3,), np.int32), pe)
    table = checkpoint.table_rows(["box"], config.policies, pe, pe)
    res = {"table": table, "results": results, "objects": ["box"], "fingerprint": "f" * 16,
           "config": config, "timings": {"contexts": 1.0, "choose": 3.0},
           "trial_counts": {"requested": 120, "simulated": 70}}
    learn_cli.write_learn_outputs(tmp_path, res, 4.0, tiny_theta0)
    assert (tmp_path / "table.md").read_text() == learn_cli.format_table(table) + "\n"
    assert json.loads((tmp_path / "table.json").read_text())["table"] == table
    cfg = io.load_json(tmp_path / "config.json")
    assert cfg["theta0"] == "test" and cfg["config"]["policies"] == ["sern", "greedy"]
    np.testing.assert_array_equal(io.load_npz(tmp_path / "results.npz")["paper_eval"], pe)
    report = (tmp_path / "report.md").read_text()
    assert "choose 3 s" in report and "they overlap" in report and "s (75%)" not in report
    assert "70 simulated for 120 policy grasps" in report
    assert io.load_json(tmp_path / "metadata.json")["trial_counts"] == {
        "requested": 120, "simulated": 70}


def test_check_out_refuses_a_file(tmp_path):
    f = tmp_path / "f"
    f.write_text("")
    with pytest.raises(ValueError, match="not a directory"):
        learn_cli._check_out(str(f))
    learn_cli._check_out(str(tmp_path / "new" / "deeper"))  # a creatable path is fine


# ----------------------------------------------------------------------------- reproduce


def test_reproduce_summary_helpers():
    table = [
        {"object": "a", "policy": "sern", "rounds": [40.0, 80.0]},
        {"object": "a", "policy": "greedy", "rounds": [40.0, 60.0]},
        {"object": "b", "policy": "sern", "rounds": [40.0, 20.0]},
        {"object": "b", "policy": "greedy", "rounds": [40.0, 60.0]},
        {"object": "c", "policy": "sern", "rounds": [40.0, 60.0]},
        {"object": "c", "policy": "greedy", "rounds": [40.0, 60.0]},
    ]
    summary = {"policies": {"sern": {"regret_T_mean": 12.34}, "ucb": {"regret_T_mean": 5}}}
    assert reproduce._regret_line(summary) == "sern R_T=12.3, ucb R_T=5.0"
    assert reproduce._regret_line({"policies": {"x": {}}}) == "see regret/report.md"


def test_reproduce_without_theta0_fails_before_any_work(tmp_path, monkeypatch):
    monkeypatch.setattr(artifacts, "DATA_DIR", tmp_path / "no_theta0")
    artifacts._load.cache_clear()

    def unreachable(*a, **k):
        raise AssertionError("reproduce started work without θ0")

    args = argparse.Namespace(quick=True, out=str(tmp_path / "run"), no_progress=True)
    with pytest.raises(ValueError, match="no pretrained network"):
        reproduce.run(args, check_run=unreachable, regret_defaults=None,
                      run_regret=unreachable, regret_figures=unreachable,
                      learn_figures=unreachable)
    assert not (tmp_path / "run").exists()


def test_reproduce_counts_the_checks_of_a_real_report(tmp_path):
    # The layout `sern check` writes (proofs_check.report.build_json): a "checks" list.
    doc = {"checks": [{"name": "a", "ok": True}, {"name": "b", "ok": False}],
           "all_as_expected": False}
    assert [r["name"] for r in reproduce._checks(doc)] == ["a", "b"]
    with pytest.raises(ValueError, match="no checks"):
        reproduce._checks({"results": [{"ok": True}]})
    regret = tmp_path / "regret"
    regret.mkdir()
    (regret / "summary.json").write_text(json.dumps({"policies": {"softmax": {
        "regret_T_mean": 1.0}}}))
    table = [{"object": "o", "policy": "sern", "rounds": [50.0],
              "lowvar_rounds": [30.0, 61.0]},
             {"object": "o", "policy": "greedy", "rounds": [40.0],
              "lowvar_rounds": [30.0, 64.0]}]
    text = reproduce._summary(doc, 1, regret, table, {"check_s": 1.0}, tmp_path)
    assert "1/2 verdicts as expected" in text and "NOT ALL AS EXPECTED" in text
    assert "better on" not in text  # no win counts on unresolved differences
    assert "final round: sern 61%, greedy 64%" in text


def test_reproduce_summary_leads_with_paired_t_intervals_and_holm(tmp_path):
    import numpy as np
    from scipy import stats as sps

    from sern_jax.infra import io

    rng = np.random.default_rng(0)
    r1, o, q, s = 3, 2, 3, 6  # rounds 0..2, 2 objects, 3 policies, 6 seeds
    lowvar = rng.uniform(0.4, 0.9, (r1, o, q, s))
    lowvar[-1, :, 0, :] = lowvar[-1, :, 2, :] + 0.10  # SERN clearly above greedy
    paper = rng.integers(0, 6, (r1, o, q, s)) / 5.0
    learn = tmp_path / "learn"
    learn.mkdir()
    io.save_npz(learn / "results.npz", paper_eval=paper, lowvar_eval=lowvar)
    io.save_json(learn / "config.json", {"config": {"policies": ["sern", "egreedy", "greedy"]}})
    doc = {"checks": [{"name": "a", "ok": True}]}
    regret = tmp_path / "regret"
    regret.mkdir()
    (regret / "summary.json").write_text(json.dumps({"policies": {}}))
    table = [{"object": "x", "policy": p, "rounds": [50.0]} for p in ("sern", "greedy")]
    text = reproduce._summary(doc, 0, regret, table, {"check_s": 1.0}, tmp_path,
                              learn_dir=learn)
    lines = text.splitlines()
    lead = next(i for i, ln in enumerate(lines) if ln.startswith("grasp learning"))
    assert "Holm over the 4 differences" in lines[lead] and "Student-t" in lines[lead]
    d = 100 * (lowvar[-1, :, 0, :] - lowvar[-1, :, 2, :]).mean(0)
    half = sps.t.ppf(0.975, s - 1) * d.std(ddof=1) / np.sqrt(s)
    want = f"SERN − greedy, fixed-pose evaluation: {d.mean():+.1f} ± {half:.1f} points"
    row = next(ln for ln in lines if want in ln)
    assert row.endswith(": sign resolved")
    assert "better on" not in text


class _RunnerReached(Exception):
    """Raised by the stand-in for driver.run: the command got past its run-directory check."""


def _learn(out, *extra):
    from sern_jax.commands import main as cli

    return cli.main(["grasp", "learn", "pipe_tee", "--no-progress", "--no-figures",
                     "--seeds", "2", "--rounds", "1", "--out", str(out), *extra])


def _listing(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_learn_run_dir_check_is_ios(tmp_path, monkeypatch, capsys):
    """`sern grasp learn` checks its run directory with io.check_run_dir (config.json and
    the checkpoint): another run's directory without a checkpoint (a finished `sern regret`
    run, or a learn run whose checkpoint was removed) is refused in one line, exit 2, left
    byte-identical and the runner never starts; the same settings resume (the runner is
    reached); other settings are refused whichever file holds the fingerprint."""
    from sern_jax.grasp.online import driver

    reached = []

    def fake_run(config, specs, out, theta0=None, **kw):
        fp = online_config.run_fingerprint(config, specs, theta0)
        reached.append(fp)
        io.save_npz(out / "checkpoint.npz", fingerprint=np.str_(fp), next_round=np.int64(1))
        io.save_json(out / "config.json", {"fingerprint": fp})
        raise _RunnerReached

    monkeypatch.setattr(driver, "run", fake_run)
    other = tmp_path / "regret_run"  # another command's finished run: config.json only
    other.mkdir()
    io.save_json(other / "config.json", {"fingerprint": "0123456789abcdef"})
    before = _listing(other)
    assert _learn(other) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # not a learning run's directory (no checkpoint.npz): named neutrally, "a different run"
    assert len(err) == 1 and "holds a different run (fingerprint 0123456789abcdef" \
        in err[0] and "--out" in err[0], err
    assert _listing(other) == before and not reached

    run = tmp_path / "learn"
    with pytest.raises(_RunnerReached):  # a new run
        _learn(run)
    with pytest.raises(_RunnerReached):  # the same settings resume
        _learn(run)
    assert len(reached) == 2 and reached[0] == reached[1]
    capsys.readouterr()
    before = _listing(run)
    assert _learn(run, "--explore", "3") == 2  # other settings: checkpoint and config.json
    (run / "checkpoint.npz").unlink()
    before_config_only = _listing(run)
    assert _learn(run, "--explore", "3") == 2  # config.json alone still refuses
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "holds a different learning run" in err[0], err  # checkpoint
    assert "holds a different run (fingerprint" in err[1], err  # config.json alone
    assert _listing(run) == before_config_only and len(reached) == 2
    assert set(before) - set(before_config_only) == {"checkpoint.npz"}
