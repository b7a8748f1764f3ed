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


def test_flag_errors_come_before_the_gl_check(tmp_path, monkeypatch):
    """On a machine without a GL library (the H100 machine without EGL), a bad flag is still
    named first: the argument checks run before the backend is loaded. Control: with good
    flags the GL failure itself is what the user hears."""
    from sern_jax.grasp.world import pictures

    def no_gl(backend):
        raise RuntimeError("no GL here")

    monkeypatch.setattr(pictures, "use_gl", no_gl)
    with pytest.raises(ValueError, match="--trials"):
        show.run(_parse(["box", "--trials", "-1", "--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="exactly one of OBJECT or --mesh"):
        show.run(_parse(["--out", str(tmp_path)]))
    with pytest.raises(ValueError, match="--gl auto: no GL here"):
        show.run(_parse(["box", "--out", str(tmp_path)]))


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


def _sern(argv, env_extra, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    env.update(env_extra)
    code = f"import sys; from sern_jax.commands.main import main; sys.exit(main({argv!r}))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=600, cwd=tmp_path)


def test_commands_that_render_nothing_ignore_an_unloadable_mujoco_gl(tmp_path):
    # MUJOCO_GL=bogus makes a plain `import mujoco` raise (as MUJOCO_GL=egl does where no EGL
    # loads); the grasp layer imports mujoco with OpenGL off and leaves the variable as it was.
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    env["MUJOCO_GL"] = "bogus"
    plain = subprocess.run([sys.executable, "-c", "import mujoco"], env=env,
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode != 0 and "MUJOCO_GL" in plain.stderr  # the control
    script = ("import os\n"
              "from sern_jax.grasp.world import objects, scene, sim\n"
              "model = scene.build_scene(objects.make_object('small_box'), seed=0)\n"
              "res = sim.GraspSimulator(model, 'native', num_threads=1).run_trials(\n"
              "    scene.centred_grasp(model)[None], sim.sample_noise(__import__('jax').random.key(0), 1))\n"
              "assert res.success.shape == (1,)\n"
              "assert os.environ['MUJOCO_GL'] == 'bogus'\n")
    res = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    out = tmp_path / "norender"
    res = _sern(["grasp", "show", "small_box", "--trials", "0", "--no-render", "--out",
                 str(out)], {"MUJOCO_GL": "bogus"}, tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "figures" / "depth_candidates.png").exists()
    assert not (out / "figures" / "scene.png").exists()


@pytest.mark.parametrize("env_extra,hint", [
    ({"MUJOCO_GL": "egl", "PYOPENGL_PLATFORM": "osmesa"}, "--gl osmesa"),  # EGL cannot load
    ({"MUJOCO_GL": "bogus"}, "pick one of egl, osmesa, glfw"),
])
def test_rendering_without_a_loadable_backend_is_one_line_before_any_work(env_extra, hint,
                                                                          tmp_path):
    out = tmp_path / "run"
    res = _sern(["grasp", "show", "small_box", "--trials", "0", "--out", str(out)], env_extra,
                tmp_path)
    assert res.returncode == 2, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert "--gl auto" in lines[0] and hint in lines[0] and "--no-render" in lines[0]
    assert not out.exists()
