"""Tests for `sern grasp show` (sern_jax.commands.grasp_show)."""

import argparse
import os
import subprocess
import sys

import numpy as np
import pytest

from sern_jax.commands import grasp_show as show


def _parse(argv):
    parser = argparse.ArgumentParser()
    show.add_parser(parser.add_subparsers())
    return parser.parse_args(["show", *argv])


def test_help_explains_outputs(capsys):
    parser = argparse.ArgumentParser()
    show.add_parser(parser.add_subparsers())
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["show", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for needle in (
        "depth_candidates.png",
        "scene.png",
        "success probability",
        "--mesh",
        "--seed",
        "--out",
        "MUJOCO_GL",
    ):
        assert needle in text, needle


def test_bad_arguments_raise_clearly(tmp_path):
    with pytest.raises(ValueError, match="exactly one of OBJECT or --mesh"):
        show.run(_parse(["--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="exactly one of OBJECT or --mesh"):
        show.run(_parse(["box", "--mesh", "x.obj", "--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="unknown object 'no_such_thing'"):
        show.run(_parse(["no_such_thing", "--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="--trials"):
        show.run(_parse(["box", "--trials", "-1", "--out", str(tmp_path)]))


def test_show_writes_pictures_and_results(tmp_path):
    """End to end in a fresh process (MUJOCO_GL must be set before mujoco is imported)."""
    out = tmp_path / "show"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    code = (
        "import sys; from sern_jax.commands.main import main; "
        f"sys.exit(main(['grasp', 'show', 'small_box', '--trials', '1', '--out', {str(out)!r}]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    import matplotlib.image

    for name in ("depth_candidates.png", "scene.png"):
        img = matplotlib.image.imread(out / "figures" / name)
        assert img.ndim == 3 and img.shape[0] > 200 and img.std() > 0.05, name
    results = np.load(out / "results.npz")
    assert results["grasps"].shape == (64, 4) and results["depth"].shape == (96, 96)
    valid = results["valid"]
    assert valid.sum() > 0
    prob = results["prob"]
    assert np.all((prob[valid] >= 0) & (prob[valid] <= 1))
    assert np.all(prob[~valid] == 0)
    assert (out / "config.json").exists() and (out / "metadata.json").exists()
