"""Tests for sern_jax.grasp.online.benchmark (the versioned grasp-exploration benchmarks) and
``sern grasp learn --benchmark``: the fixture loads, a family whose geometry moved is
refused, every schema problem is one line naming the file and the field, the tuned
hyperparameters reach the OnlineConfig (a user's learner runs with its defaults), the flags a
benchmark fixes are refused (exit 2, one line naming the flag, nothing written), and one small
run end to end."""

from __future__ import annotations

import copy
import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sern_jax.commands import main as cli
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import benchmark, driver
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import registry, sern

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "tests" / "data" / "benchmark_fixture.json"


def _raw() -> dict:
    return json.loads(FIXTURE.read_text())


def _write(tmp_path: Path, doc: dict, name: str = "bench.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _main(argv) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return exc.code


def _tree(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


# ----------------------------------------------------------------------------- loading


def test_fixture_loads_and_rebuilds_its_objects():
    bench = benchmark.load_file(FIXTURE)
    assert (bench.name, bench.version, bench.seeds) == ("benchmark_fixture", 1, 3)
    assert [s.name for s in bench.objects] == ["wedge_0"]
    assert [s.name for s in bench.tuning_objects] == ["wedge_1"]
    assert bench.objects[0] == objects.wedge(0)
    assert bench.world == (context_lib.ContextConfig(), sim_lib.TrialConfig())
    assert bench.learners["sern"] == {"alpha": 0.02}
    assert bench.metrics["primary"] == ["curve_area", "explore_success"]
    assert bench.raw == _raw()
    # the file's entries are what this code writes (benchmark.object_entry)
    assert _raw()["objects"] == [benchmark.object_entry("wedge_0")]
    # the fixture assumes the shipped θ0 (after a new `sern grasp pretrain --install`, write
    # its manifest's theta0_sha256 into the fixture)
    manifest = json.loads((artifacts.DATA_DIR / "manifest.json").read_text())
    assert bench.theta0_sha256 == manifest["theta0_sha256"]


def test_object_digest_sees_vertices_and_mass_only_to_the_nanometre():
    spec = objects.wedge(3)
    digest = benchmark.object_digest(spec)
    assert len(digest) == 64 and digest == benchmark.object_digest(objects.wedge(3))
    moved = dataclasses.replace(spec, geoms=(dataclasses.replace(
        spec.geoms[0], vertices=((spec.geoms[0].vertices[0][0] + 1e-6,)
                                 + spec.geoms[0].vertices[0][1:],)
        + spec.geoms[0].vertices[1:]),))
    assert benchmark.object_digest(moved) != digest
    assert benchmark.object_digest(dataclasses.replace(spec, mass=spec.mass * 1.01)) != digest
    nudged = dataclasses.replace(spec, geoms=(dataclasses.replace(
        spec.geoms[0], vertices=tuple(tuple(x + 1e-13 for x in v)
                                      for v in spec.geoms[0].vertices)),))
    assert benchmark.object_digest(nudged) == digest  # a last-bit difference is no change


def test_a_family_whose_geometry_moved_is_refused(tmp_path, monkeypatch):
    doc = _raw()
    doc["objects"][0]["vertices_sha256"] = "0" * 64
    path = _write(tmp_path, doc)
    with pytest.raises(ValueError) as exc:
        benchmark.load_file(path)
    line = str(exc.value)
    assert "\n" not in line and str(path) in line and "wedge_0" in line, line
    # the family's code changed (here: the wedge builder), the file did not
    real = benchmark.FAMILIES["wedge"]

    def longer(index):
        spec = real[0](index)
        g = spec.geoms[0]
        return dataclasses.replace(spec, geoms=(dataclasses.replace(
            g, vertices=tuple((1.1 * v[0], v[1], v[2]) for v in g.vertices)),))

    monkeypatch.setitem(benchmark.FAMILIES, "wedge", (longer, real[1]))
    with pytest.raises(ValueError, match=r"object wedge_0 rebuilds to geometry sha256"):
        benchmark.load_file(FIXTURE)


def _set(doc, dotted, value):
    """Sets (or deletes) the field at a dotted path (list items by index), making the
    objects on the way."""
    *head, last = dotted.split(".")
    for key in head:
        doc = doc[int(key)] if isinstance(doc, list) else doc.setdefault(key, {})
    last = int(last) if isinstance(doc, list) else last
    if value is _DELETE:
        del doc[last]
    else:
        doc[last] = value


_DELETE = object()


@pytest.mark.parametrize("field, value, named", [
    ("seeds", _DELETE, "missing field 'seeds'"),
    ("leaderboard", {}, "unknown field 'leaderboard'"),
    ("seeds", "40", "'seeds' holds a string, not an integer"),
    ("seeds", True, "'seeds' holds true or false"),
    ("seeds", 0, "'seeds' must be an integer >= 1"),
    ("schema", 2, "schema 2 is not one this sern_jax reads"),
    ("name", "Wedges!", "'name' must be lower-case"),
    ("objects", [], "'objects' must name at least one object"),
    ("objects.0.index", 64, "'objects[0].index'"),
    ("objects.0.name", "wedge_5", "'objects[0].name' 'wedge_5' is not wedge_0"),
    ("objects.0.family", "cube", "'objects[0].family' 'cube'"),
    ("objects.0.colour", "red", "unknown field 'objects[0].colour'"),
    ("objects.0.params.height", 0.03, "object wedge_0's 'params'"),
    ("tuning_objects.0", "wedge_1", "'tuning_objects[0]' holds a string"),
    ("protocol.rounds", 0, "protocol.rounds must be an integer >= 1"),
    ("protocol.core_set", "kmeans", "protocol.core_set must be dpp, random or none"),
    ("protocol.eval_trials", 0, "protocol.eval_trials must be >= 1 when protocol.eval_poses"),
    ("protocol.backend", "bullet", "protocol.backend must be one of"),
    ("protocol.explore", 4.5, "'protocol.explore' holds a number, not an integer"),
    ("protocol.temperature", 1, "unknown field 'protocol.temperature'"),
    ("world.context.scene.finger_force", "strong", "'world.context.scene.finger_force' holds"),
    ("world.context.gravity", 9.81, "unknown field 'world.context.gravity'"),
    ("world.trial.friction_range", [0.3], "'world.trial.friction_range' must be a list"),
    ("world.trial.friction_range", [0.8, 0.3], "world.trial"),
    ("world.physics", {}, "unknown field 'world.physics'"),
    ("learners.ucb9", {}, "'learners.ucb9' is not a registered learner"),
    ("learners.sern.epsilon", 0.1, "'learners.sern.epsilon' is not a hyperparameter of sern"),
    ("learners.sern.alpha", -1.0, "'learners.sern': --alpha"),
    ("learners.greedy", [], "'learners.greedy' holds a list"),
    ("learners.neural_linucb", {"lambda_prior": 1.0}, "share its value"),
    ("metrics.primary", [], "'metrics.primary' must name at least one metric"),
    ("metrics.primary", ["curve_area", "curve_area"], "'metrics.primary' must be a list"),
    ("theta0.sha256", "c04b2f0c", "'theta0.sha256' must be a sha256 digest"),
    ("screen.rule.min_best_success", 80, "'screen.rule.min_best_success' must lie in [0, 1]"),
    ("screen.record", None, "'screen.record' holds null, not a string"),
])
def test_schema_errors_are_one_line_naming_file_and_field(field, value, named, tmp_path):
    doc = copy.deepcopy(_raw())
    _set(doc, field, value)
    path = _write(tmp_path, doc)
    with pytest.raises(ValueError) as exc:
        benchmark.load_file(path)
    line = str(exc.value)
    assert "\n" not in line and line.startswith(str(path)) and named in line, line


def test_damaged_files_and_an_object_in_both_sets(tmp_path):
    for text in ("{", "[1, 2]", ""):
        path = tmp_path / "b.json"
        path.write_text(text)
        with pytest.raises(ValueError, match=str(path)):
            benchmark.load_file(path)
    doc = _raw()
    doc["tuning_objects"].append(doc["objects"][0])
    with pytest.raises(ValueError, match="in both 'objects' and 'tuning_objects'"):
        benchmark.load_file(_write(tmp_path, doc))


def test_world_overrides_reach_the_configs(tmp_path):
    doc = _raw()
    doc["world"] = {"context": {"scene": {"finger_force": 10}, "noise": True},
                    "trial": {"friction_range": [0.2, 0.5], "pos_noise_std": 0.004}}
    context, trial = benchmark.load_file(_write(tmp_path, doc)).world
    assert context.scene.finger_force == 10.0 and isinstance(context.scene.finger_force, float)
    assert context.noise is True and context.camera == context_lib.ContextConfig().camera
    assert trial.friction_range == (0.2, 0.5) and trial.pos_noise_std == 0.004
    assert trial.lift_steps == sim_lib.TrialConfig().lift_steps


def test_shipped_benchmarks_load_and_ship_in_the_wheel(tmp_path, monkeypatch):
    for name in benchmark.names():  # every shipped file loads (its objects rebuild)
        assert benchmark.load(name).name == name
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "data/benchmarks/*.json" in data["tool"]["setuptools"]["package-data"][
        "sern_jax.grasp"]
    monkeypatch.setattr(benchmark, "BENCHMARK_DIR", tmp_path)
    (tmp_path / "benchmark_fixture.json").write_text(FIXTURE.read_text())
    assert benchmark.names() == ("benchmark_fixture",)
    assert benchmark.resolve("benchmark_fixture").objects[0].name == "wedge_0"
    with pytest.raises(ValueError, match=r"--benchmark 'wedgez': no such benchmark; known: "
                                         r"benchmark_fixture"):
        benchmark.resolve("wedgez")
    (tmp_path / "other.json").write_text(FIXTURE.read_text())  # its name is not its file's
    with pytest.raises(ValueError, match="'name' is 'benchmark_fixture', not the file's"):
        benchmark.load("other")


# ----------------------------------------------------------------------------- runs


@dataclasses.dataclass(frozen=True)
class MineConfig:
    mine_width: float = dataclasses.field(default=0.5, metadata={
        "flag": "--mine-width", "help": "a user's learner's own hyperparameter"})


def _greedy_like(model, train, config):
    return registry.LEARNERS["greedy"].make(model, train, registry.make_config("greedy"))


def test_online_config_maps_the_tuned_hyperparameters():
    bench = benchmark.load_file(FIXTURE)
    config = benchmark.online_config(bench)
    assert config.policies == ("sern", "egreedy", "greedy", "ensemble_ts", "neural_lints")
    assert (config.num_seeds, config.rounds, config.explore, config.evaluate) == (3, 2, 4, 1)
    assert (config.eval_poses, config.eval_trials, config.fit_steps) == (2, 2, 2)
    assert (config.core_set, config.loss, config.seed, config.backend) == (
        "dpp", "bce", 0, "native")
    assert config.learner_config("sern").alpha == 0.02
    assert config.learner_config("ensemble_ts").ensemble_heads == "shared"
    assert config.learner_config("neural_lints").nl_sigma2 == "pooled"
    small = benchmark.online_config(bench, ("greedy", "sern"), seeds=2, rounds=1)
    assert (small.policies, small.num_seeds, small.rounds) == (("greedy", "sern"), 2, 1)
    for kwargs, named in (({"seeds": 4}, "seeds must be an integer in [1, 3]"),
                          ({"rounds": 3}, "rounds must be an integer in [1, 2]"),
                          ({"hyper": {"alpha": 0.1}}, "--alpha: benchmark benchmark_fixture"),
                          ({"policies": ("nope",)}, "unknown policy 'nope'")):
        with pytest.raises(ValueError, match=named.replace("[", r"\[").replace("]", r"\]")):
            benchmark.online_config(bench, **kwargs)


def test_a_users_learner_runs_with_its_registry_defaults(monkeypatch):
    bench = benchmark.load_file(FIXTURE)
    monkeypatch.setitem(registry.LEARNERS, "mine",
                        registry.LearnerSpec(_greedy_like, MineConfig, "a user's learner"))
    config = benchmark.online_config(bench, ("mine", "sern"))
    assert config.learner_config("mine") == MineConfig()
    assert config.learner_config("sern").alpha == 0.02
    tuned = benchmark.online_config(bench, ("mine",), hyper={"mine_width": 0.75})
    assert tuned.learner_config("mine").mine_width == 0.75
    # a learner outside the benchmark sharing a tuned hyperparameter (one field name, one
    # value in a run): its defaults alone, refused beside the learner the value is tuned for
    monkeypatch.setitem(registry.LEARNERS, "my_sern",
                        registry.LearnerSpec(sern.sern, sern.SernConfig, "SERN, mine"))
    assert benchmark.online_config(bench, ("my_sern",)).learner_config("my_sern").alpha == 0.05
    with pytest.raises(ValueError, match="my_sern is not a learner of benchmark"):
        benchmark.online_config(bench, ("my_sern", "sern"))


def test_theta0_digest_is_checked(tmp_path, tiny_theta0):
    bench = benchmark.load_file(FIXTURE)
    with pytest.raises(ValueError) as exc:
        benchmark.check_theta0(bench, tiny_theta0, "--theta0 mine")
    line = str(exc.value)
    assert "\n" not in line and line.startswith("--theta0 mine") and bench.theta0_sha256[:16] \
        in line and "benchmark_fixture.json" in line, line
    same = tiny_theta0._replace(manifest={"theta0_sha256": bench.theta0_sha256})
    benchmark.check_theta0(bench, same)


def test_select_runs_a_part():
    bench = benchmark.load_file(FIXTURE)
    assert [s.name for s in benchmark.select(bench, ())] == ["wedge_0"]
    assert [s.name for s in benchmark.select(bench, ["wedge_1"])] == ["wedge_1"]  # tuning
    with pytest.raises(ValueError, match="OBJECT 'wedge_7' is not an object of benchmark"):
        benchmark.select(bench, ["wedge_7"])


# ----------------------------------------------------------------------------- command line


def _argv(*extra, bench=str(FIXTURE)):
    return ["grasp", "learn", "--benchmark", bench, "--no-progress", "--no-figures",
            "--out", "learn", *extra]


@pytest.mark.parametrize("extra, named", [
    (["--explore", "4"], "--explore: benchmark benchmark_fixture fixes its protocol"),
    (["--explore", "20"], "--explore"),  # typed with the parser's default: still refused
    (["--eval-poses", "8"], "--eval-poses"),
    (["--eval-trials", "16"], "--eval-trials"),
    (["--evaluate", "5"], "--evaluate"),
    (["--fit-steps", "40"], "--fit-steps"),
    (["--core-set", "random"], "--core-set"),
    (["--loss", "l1"], "--loss"),
    (["--seed", "1"], "--seed"),
    (["--alpha", "0.05"], "--alpha: benchmark benchmark_fixture fixes the hyperparameters"),
    (["--epsilon", "0.2"], "--epsilon"),
    (["--ensemble-heads", "networks"], "--ensemble-heads"),
    (["--lambda-prior", "1.0"], "--lambda-prior"),  # neural_lints's, shared with linucb
    (["--mesh", "part.obj"], "--mesh: benchmark benchmark_fixture fixes the objects"),
    (["--mesh-units", "mm"], "--mesh-units"),
    (["--seeds", "4"], "--seeds must be an integer in [1, 3]"),
    (["--rounds", "3"], "--rounds must be an integer in [1, 2]"),
    (["--policies", "sern,nope"], "unknown policy 'nope'"),
    (["wedge_9"], "OBJECT 'wedge_9' is not an object of benchmark benchmark_fixture"),
    (["--regret-grasps", "5", "--regret-trials", "1"], "--regret-grasps must be <="),
    (["--nu", "nan"], "--nu"),  # a learner the benchmark does not tune: its own checks
])
def test_learn_refuses_what_the_benchmark_fixes(extra, named, tmp_path, monkeypatch, capsys):
    def unreachable(*a, **k):
        raise AssertionError("bad input reached driver.run")

    monkeypatch.setattr(driver, "run", unreachable)
    monkeypatch.chdir(tmp_path)
    before = _tree(tmp_path)
    assert _main(_argv(*extra)) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and named in lines[0] and "Traceback" not in err, err
    assert _tree(tmp_path) == before


def test_learn_refuses_unknown_benchmarks_and_another_theta0(tmp_path, monkeypatch, capsys):
    def unreachable(*a, **k):
        raise AssertionError("bad input reached driver.run")

    monkeypatch.setattr(driver, "run", unreachable)
    monkeypatch.setattr(benchmark, "BENCHMARK_DIR", tmp_path / "shipped")
    (tmp_path / "shipped").mkdir()
    (tmp_path / "shipped" / "benchmark_fixture.json").write_text(FIXTURE.read_text())
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    doc = _raw()
    doc["theta0"]["sha256"] = "ab" * 32
    other = _write(tmp_path, doc, "other_theta0.json")
    for argv, named in ((_argv(bench="wedgez"), "--benchmark 'wedgez': no such benchmark; "
                                                "known: benchmark_fixture"),
                        (_argv(bench="missing.json"), "--benchmark missing.json: no such "
                                                      "benchmark file"),
                        (_argv(bench=str(other)), "is not the θ0 benchmark benchmark_fixture "
                                                  "assumes (sha256 abababababababab")):
        assert _main(argv) == 2
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and named in lines[0], err
        assert list(work.iterdir()) == []


def test_learn_benchmark_end_to_end(tmp_path, monkeypatch, capsys):
    """`sern grasp learn --benchmark FILE --policies greedy --seeds 2 --rounds 1`: the
    benchmark's object, protocol and seeds, recorded in the run directory (about 30 s on
    2 cores)."""
    monkeypatch.chdir(tmp_path)
    argv = ["grasp", "learn", "--benchmark", str(FIXTURE), "--policies", "greedy",
            "--seeds", "2", "--rounds", "1", "--no-progress", "--no-figures", "--out", "run"]
    assert _main(argv) == 0
    run = tmp_path / "run"
    saved = json.loads((run / "config.json").read_text())
    assert saved["benchmark"] == {"name": "benchmark_fixture", "version": 1,
                                  "file": "benchmark_fixture.json", "objects": ["wedge_0"],
                                  "seeds": 2, "rounds": 1, "backend": "native"}
    assert json.loads((run / "metadata.json").read_text())["benchmark"] == saved["benchmark"]
    config = saved["config"]
    assert (config["policies"], config["num_seeds"], config["rounds"]) == (["greedy"], 2, 1)
    assert (config["explore"], config["eval_poses"], config["eval_trials"]) == (4, 2, 2)
    with np.load(run / "results.npz") as results:
        assert results["lowvar_eval"].shape == (2, 1, 1, 2)  # [R + 1, O, Q, S]
    assert "| wedge_0 | greedy |" in capsys.readouterr().out
    assert _main(argv) == 0  # the same command again: the finished run, resumed
