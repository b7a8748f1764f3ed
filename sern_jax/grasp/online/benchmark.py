"""The grasp-exploration benchmarks: versioned JSON files shipped as package data.

A benchmark fixes everything a comparison of exploration strategies needs, so that any
registered learner, a user's own included, runs on the same problem
(``sern grasp learn --benchmark NAME --policies ...``):

* ``objects`` (scored) and ``tuning_objects`` (the objects the learners' hyperparameters
  were tuned on, not scored), each rebuilt from its family and index, with the digest of
  its geometry (:func:`object_digest`): a change to the family's code that moves a vertex
  or the mass makes loading fail, naming the object and the file;
* ``world``: overrides of :class:`~sern_jax.grasp.world.context.ContextConfig` and
  :class:`~sern_jax.grasp.world.sim.TrialConfig` fields (``{}``: θ0's world);
* ``protocol``: rounds, exploration and evaluation grasps, fixed-pose evaluation size, the
  update, the root seed and the physics backend it was run with;
* ``seeds``, the tuned ``learners`` (name -> hyperparameters), the ``metrics``, the θ0 it
  assumes (``theta0.sha256``: the digest ``manifest.json`` records) and the ``screen`` rule
  the objects passed.

Shipped files live in ``sern_jax/grasp/data/benchmarks/<name>.json`` (:func:`names`,
:func:`load`); :func:`load_file` reads any file of the same schema. :func:`online_config`
turns a benchmark and a choice of learners into the run's
:class:`~sern_jax.grasp.online.config.OnlineConfig`. Every problem with a file is one line
naming the file and the field (``ValueError``).

Schema 1 (every field required, no others)::

    {"schema": 1, "name": "wedges", "version": 1, "description": "...",
     "objects": [{"name": "wedge_3", "family": "wedge", "index": 3,
                  "params": {...}, "vertices_sha256": "..."}],
     "tuning_objects": [...],
     "world": {"context": {}, "trial": {}},
     "protocol": {"rounds": 5, "explore": 20, "evaluate": 5, "eval_poses": 8,
                  "eval_trials": 16, "fit_steps": 40, "core_set": "dpp", "loss": "bce",
                  "seed": 0, "backend": "native"},
     "seeds": 40,
     "learners": {"sern": {"alpha": 0.02}, "greedy": {}, ...},
     "metrics": {"primary": [...], "secondary": [...]},
     "theta0": {"sha256": "..."},
     "screen": {"rule": {"max_greedy_success": 0.6, "min_best_success": 0.8},
                "record": "experiments/results/benchmark/screen"}}
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import config as config_lib
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import registry

__all__ = [
    "BENCHMARK_DIR",
    "FAMILIES",
    "SCHEMA",
    "Benchmark",
    "check_theta0",
    "load",
    "load_file",
    "names",
    "object_digest",
    "object_entry",
    "online_config",
    "resolve",
    "select",
]

SCHEMA = 1  # the version of the file format this module reads
BENCHMARK_DIR = artifacts.DATA_DIR / "benchmarks"  # sern_jax/grasp/data/benchmarks

# object families a benchmark can rebuild: family -> (build(index), params(index))
FAMILIES: dict[str, tuple[Callable[[int], objects_lib.ObjectSpec], Callable[[int], dict]]] = {
    "wedge": (objects_lib.wedge, objects_lib.wedge_params),
}

_FIELDS = {"schema": int, "name": str, "version": int, "description": str, "objects": list,
           "tuning_objects": list, "world": dict, "protocol": dict, "seeds": int,
           "learners": dict, "metrics": dict, "theta0": dict, "screen": dict}
_OBJECT_FIELDS = {"name": str, "family": str, "index": int, "params": dict,
                  "vertices_sha256": str}
_PROTOCOL_FIELDS = {"rounds": int, "explore": int, "evaluate": int, "eval_poses": int,
                    "eval_trials": int, "fit_steps": int, "core_set": str, "loss": str,
                    "seed": int, "backend": str}
_WORLD_FIELDS = {"context": dict, "trial": dict}
_METRICS_FIELDS = {"primary": list, "secondary": list}
_THETA0_FIELDS = {"sha256": str}
_SCREEN_FIELDS = {"rule": dict, "record": str}
_RULE_FIELDS = {"max_greedy_success": (int, float), "min_best_success": (int, float)}
_NAME = re.compile(r"[a-z0-9][a-z0-9_]*")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_TYPE_NAMES = {dict: "an object", list: "a list", str: "a string", int: "an integer",
               float: "a number", bool: "true or false"}


class Benchmark(NamedTuple):
    """A loaded, checked benchmark (:func:`load`, :func:`load_file`)."""

    name: str
    version: int
    path: Path  # the file it was read from
    description: str
    objects: tuple[objects_lib.ObjectSpec, ...]  # the scored objects, rebuilt
    tuning_objects: tuple[objects_lib.ObjectSpec, ...]  # tuned on, not scored
    world: tuple[context_lib.ContextConfig, sim_lib.TrialConfig]
    protocol: dict  # the "protocol" object as in the file
    seeds: int
    learners: dict[str, dict]  # learner name -> its tuned hyperparameters (field -> value)
    metrics: dict  # {"primary": [...], "secondary": [...]}
    theta0_sha256: str  # the digest of the θ0 it assumes (manifest.json's theta0_sha256)
    raw: dict  # the whole file


# ----------------------------------------------------------------------------- objects


def object_digest(spec: objects_lib.ObjectSpec) -> str:
    """The sha256 of an object's geometry and mass: every geom's type, size, position,
    orientation and vertices, then the mass, each number rounded to 1e-9 (nanometres; a
    last-bit difference of a platform's ``tan`` cannot change it, a moved vertex does), as
    JSON (the ``vertices_sha256`` of a benchmark's object entry)."""

    def num(x) -> float:
        return round(float(x), 9) + 0.0  # + 0.0: -0.0 and 0.0 alike

    geoms = [[g.type, [num(x) for x in g.size], [num(x) for x in g.pos],
              [num(x) for x in g.quat], [[num(x) for x in v] for v in g.vertices]]
             for g in spec.geoms]
    text = json.dumps({"geoms": geoms, "mass": num(spec.mass)}, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def object_entry(name: str) -> dict:
    """The benchmark entry of object ``name`` (``<family>_<index>``) as this code builds
    it: name, family, index, params and geometry digest (how a benchmark file is written)."""
    family, _, index = name.rpartition("_")
    if family not in FAMILIES or not index.isdigit():
        raise ValueError(f"object {name!r} is not a member of a benchmark family "
                         f"({', '.join(f'{f}_<index>' for f in FAMILIES)})")
    build, params = FAMILIES[family]
    return {"name": name, "family": family, "index": int(index), "params": params(int(index)),
            "vertices_sha256": object_digest(build(int(index)))}


# ----------------------------------------------------------------------------- files


def names() -> tuple[str, ...]:
    """The shipped benchmarks' names (the files in :data:`BENCHMARK_DIR`), sorted."""
    if not BENCHMARK_DIR.is_dir():
        return ()
    return tuple(sorted(p.stem for p in BENCHMARK_DIR.glob("*.json")))


def _known() -> str:
    shipped = names()
    return (f"known: {', '.join(shipped)}" if shipped else "none is shipped with this install")


def load(name: str) -> Benchmark:
    """The shipped benchmark ``name`` (its file's name is its ``name`` field)."""
    if name not in names():
        raise ValueError(f"no benchmark named {name!r}; {_known()}")
    bench = load_file(BENCHMARK_DIR / f"{name}.json")
    if bench.name != name:
        raise ValueError(f"{bench.path}: 'name' is {bench.name!r}, not the file's name "
                         f"{name!r}")
    return bench


def resolve(name_or_path: str, flag: str = "--benchmark") -> Benchmark:
    """A benchmark by shipped name, or by the path of a ``.json`` file of the schema; an
    unknown name is one line naming ``flag`` and listing the known names."""
    text = str(name_or_path).strip()
    if text.endswith(".json") or "/" in text or "\\" in text:
        if not Path(text).is_file():
            raise ValueError(f"{flag} {text}: no such benchmark file")
        return load_file(text)
    if text not in names():
        raise ValueError(f"{flag} {text!r}: no such benchmark; {_known()} (or give the path "
                         f"of a benchmark .json file)")
    return load(text)


def load_file(path: str | Path) -> Benchmark:
    """The benchmark in ``path``, checked against schema 1 (types, unknown and missing
    fields, learners and their hyperparameters, protocol, world, the objects' digests)."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read this benchmark ({exc.strerror or exc})") from None
    except (ValueError, UnicodeDecodeError):
        raise ValueError(f"{path} is not valid JSON (a damaged benchmark file)") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path} holds {_kind(raw)}, not a benchmark's JSON object")
    if isinstance(raw.get("schema"), int) and not isinstance(raw["schema"], bool) \
            and raw["schema"] != SCHEMA:
        raise ValueError(f"{path}: schema {raw['schema']} is not one this sern_jax reads "
                         f"(schema {SCHEMA}); update sern_jax")
    _check_fields(raw, _FIELDS, path, "")
    if not _NAME.fullmatch(raw["name"]):
        raise ValueError(f"{path}: 'name' must be lower-case letters, digits and _, got "
                         f"{raw['name']!r}")
    for key in ("version", "seeds"):
        if raw[key] < 1:
            raise ValueError(f"{path}: {key!r} must be an integer >= 1, got {raw[key]}")
    objects = _objects(raw["objects"], path, "objects")
    tuning = _objects(raw["tuning_objects"], path, "tuning_objects")
    if not objects:
        raise ValueError(f"{path}: 'objects' must name at least one object")
    both = {s.name for s in objects} & {s.name for s in tuning}
    if both:
        raise ValueError(f"{path}: {sorted(both)[0]!r} is in both 'objects' and "
                         "'tuning_objects' (tuning objects are not scored)")
    _check_fields(raw["world"], _WORLD_FIELDS, path, "world.")
    world = (_replace(context_lib.ContextConfig(), raw["world"]["context"], path,
                      "world.context"),
             _replace(sim_lib.TrialConfig(), raw["world"]["trial"], path, "world.trial"))
    protocol = raw["protocol"]
    _check_fields(protocol, _PROTOCOL_FIELDS, path, "protocol.")
    learners = _learners(raw["learners"], path)
    _check_fields(raw["metrics"], _METRICS_FIELDS, path, "metrics.")
    for key in _METRICS_FIELDS:
        items = raw["metrics"][key]
        if not all(isinstance(m, str) and m for m in items) or len(set(items)) != len(items):
            raise ValueError(f"{path}: 'metrics.{key}' must be a list of distinct metric "
                             "names")
    if not raw["metrics"]["primary"]:
        raise ValueError(f"{path}: 'metrics.primary' must name at least one metric")
    _check_fields(raw["theta0"], _THETA0_FIELDS, path, "theta0.")
    if not _SHA256.fullmatch(raw["theta0"]["sha256"]):
        raise ValueError(f"{path}: 'theta0.sha256' must be a sha256 digest (64 lower-case "
                         "hex digits, manifest.json's theta0_sha256)")
    _check_fields(raw["screen"], _SCREEN_FIELDS, path, "screen.")
    _check_fields(raw["screen"]["rule"], _RULE_FIELDS, path, "screen.rule.")
    for key, value in raw["screen"]["rule"].items():
        if not 0 <= value <= 1:
            raise ValueError(f"{path}: 'screen.rule.{key}' must lie in [0, 1], got {value}")
    bench = Benchmark(name=raw["name"], version=raw["version"], path=path,
                      description=raw["description"], objects=objects, tuning_objects=tuning,
                      world=world, protocol=dict(protocol), seeds=raw["seeds"],
                      learners=learners, metrics=raw["metrics"],
                      theta0_sha256=raw["theta0"]["sha256"], raw=raw)
    try:  # the protocol and the tuned values as a run: OnlineConfig's own checks
        online_config(bench)
    except ValueError as exc:
        raise ValueError(f"{path}: {_protocol_names(str(exc))}") from None
    return bench


def _kind(value) -> str:
    if value is None:
        return "null"
    return _TYPE_NAMES.get(type(value), type(value).__name__)


def _check_fields(data: dict, fields: dict, path: Path, prefix: str) -> None:
    """``data`` has exactly ``fields`` (name -> type or types), each of its type."""
    for key in data:
        if key not in fields:
            raise ValueError(f"{path}: unknown field {prefix + key!r}; "
                             f"{prefix.rstrip('.') or 'a benchmark'} has "
                             f"{', '.join(fields)}")
    for key, types in fields.items():
        if key not in data:
            raise ValueError(f"{path}: missing field {prefix + key!r}")
        types = types if isinstance(types, tuple) else (types,)
        value = data[key]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            want = " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in types)
            raise ValueError(f"{path}: {prefix + key!r} holds {_kind(value)}, not {want}")


def _objects(entries: list, path: Path, where: str) -> tuple[objects_lib.ObjectSpec, ...]:
    specs, seen = [], set()
    for i, entry in enumerate(entries):
        at = f"{where}[{i}]."
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: '{where}[{i}]' holds {_kind(entry)}, not an object")
        _check_fields(entry, _OBJECT_FIELDS, path, at)
        name, family, index = entry["name"], entry["family"], entry["index"]
        if family not in FAMILIES:
            raise ValueError(f"{path}: '{at}family' {family!r} is not a benchmark family "
                             f"({', '.join(FAMILIES)})")
        build, params = FAMILIES[family]
        try:
            spec, want = build(index), params(index)
        except ValueError as exc:
            raise ValueError(f"{path}: '{at}index': {exc}") from None
        if name != f"{family}_{index}":
            raise ValueError(f"{path}: '{at}name' {name!r} is not {family}_{index} (its "
                             "family and index)")
        if name in seen:
            raise ValueError(f"{path}: object {name!r} is listed twice in {where!r}")
        seen.add(name)
        if json.loads(json.dumps(want)) != entry["params"]:
            raise ValueError(f"{path}: object {name}'s 'params' are not what the {family} "
                             f"family builds from index {index} now (its code changed): "
                             f"the benchmark cannot be rebuilt")
        digest = object_digest(spec)
        if digest != entry["vertices_sha256"]:
            raise ValueError(f"{path}: object {name} rebuilds to geometry sha256 "
                             f"{digest[:16]}, the file records "
                             f"{entry['vertices_sha256'][:16]} (the {family} family's code "
                             "changed): the benchmark cannot be rebuilt")
        specs.append(spec)
    return tuple(specs)


def _replace(config, overrides: dict, path: Path, where: str):
    """``config`` (a frozen dataclass) with ``overrides`` (field -> value; a nested
    dataclass field takes an object of its own overrides, a tuple field a list)."""
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for key, value in overrides.items():
        at = f"{where}.{key}"
        if key not in fields:
            raise ValueError(f"{path}: unknown field {at!r}; {type(config).__name__} has "
                             f"{', '.join(fields)}")
        current = getattr(config, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ValueError(f"{path}: {at!r} holds {_kind(value)}, not an object")
            changes[key] = _replace(current, value, path, at)
        elif isinstance(current, tuple):
            if (not isinstance(value, list) or len(value) != len(current)
                    or not all(_same_type(v, c) for v, c in zip(value, current))):
                raise ValueError(f"{path}: {at!r} must be a list like {list(current)}")
            changes[key] = tuple(float(v) if isinstance(c, float) else v
                                 for v, c in zip(value, current))
        elif _same_type(value, current):
            changes[key] = float(value) if isinstance(current, float) else value
        else:
            raise ValueError(f"{path}: {at!r} holds {_kind(value)}, not "
                             f"{_TYPE_NAMES.get(type(current), type(current).__name__)}")
    try:
        return dataclasses.replace(config, **changes)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {where}: {exc}") from None


def _same_type(value, default) -> bool:
    """A JSON value fits a field whose default is ``default`` (an int where a float goes)."""
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float))
    return type(value) is type(default)


def _learners(learners: dict, path: Path) -> dict[str, dict]:
    """The tuned learners, each registered, its hyperparameters its config's fields with
    valid values; learners sharing a hyperparameter (one field name) share its value."""
    if not learners:
        raise ValueError(f"{path}: 'learners' must name at least one learner")
    known = registry.hyperparameters()
    out: dict[str, dict] = {}
    for name, values in learners.items():
        if name not in registry.LEARNERS:
            raise ValueError(f"{path}: 'learners.{name}' is not a registered learner; "
                             f"registered: {', '.join(registry.names())}")
        if not isinstance(values, dict):
            raise ValueError(f"{path}: 'learners.{name}' holds {_kind(values)}, not an "
                             "object of hyperparameters")
        own = {f.name for f in dataclasses.fields(registry.LEARNERS[name].config)}
        for key in values:
            if key not in own:
                raise ValueError(f"{path}: 'learners.{name}.{key}' is not a hyperparameter "
                                 f"of {name} ({', '.join(sorted(own)) or 'it has none'})")
        try:
            registry.make_config(name, values)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: 'learners.{name}': {exc}") from None
        out[name] = dict(values)
    for a in out:  # one value per shared field name (OnlineConfig holds one)
        for b in out:
            for key in set(_effective(a, out[a])) & set(_effective(b, out[b])):
                va, vb = _effective(a, out[a])[key], _effective(b, out[b])[key]
                if a < b and va != vb:
                    raise ValueError(
                        f"{path}: 'learners.{a}.{key}' ({va!r}) and 'learners.{b}.{key}' "
                        f"({vb!r}, {'tuned' if key in out[b] else 'its default'}) differ; "
                        f"learners sharing a hyperparameter ({known[key].metadata['flag']}) "
                        "share its value")
    return out


def _effective(name: str, values: dict) -> dict:
    """Learner ``name``'s hyperparameters: ``values`` over its config's defaults."""
    return {f.name: values.get(f.name, f.default)
            for f in dataclasses.fields(registry.LEARNERS[name].config)}


def _protocol_names(message: str) -> str:
    """An OnlineConfig error in the file's words (``num_seeds`` is ``seeds``, the protocol's
    fields are ``protocol.<field>``)."""
    message = re.sub(r"\bnum_seeds\b", "seeds", message)
    return re.sub(r"(?<![-\w.])(" + "|".join(_PROTOCOL_FIELDS) + r")\b", r"protocol.\1",
                  message)


# ----------------------------------------------------------------------------- runs


def select(bench: Benchmark, object_names: Sequence[str]) -> list[objects_lib.ObjectSpec]:
    """The benchmark's objects named (a part of the run: one object, or a few); none named:
    all its scored objects. A name that is neither an object nor a tuning object of the
    benchmark is one line naming it."""
    if not object_names:
        return list(bench.objects)
    by_name = {s.name: s for s in bench.objects + bench.tuning_objects}
    out = []
    for name in object_names:
        if name not in by_name:
            raise ValueError(f"OBJECT {name!r} is not an object of benchmark {bench.name} "
                             f"(objects: {', '.join(s.name for s in bench.objects)}; tuning "
                             f"objects: {', '.join(s.name for s in bench.tuning_objects)})")
        if any(s.name == name for s in out):
            raise ValueError(f"OBJECT {name!r} given twice")
        out.append(by_name[name])
    return out


def online_config(bench: Benchmark, policies: Sequence[str] | None = None,
                  seeds: int | None = None, rounds: int | None = None,
                  hyper: dict[str, Any] | None = None) -> config_lib.OnlineConfig:
    """The run of ``policies`` (default: the benchmark's learners) on ``bench``.

    The protocol sets the sizes, the update, the root seed and the backend; a learner the
    benchmark tunes runs with its tuned hyperparameters; any other registered learner (a
    user's own) with its registry defaults, or with ``hyper`` (field -> value) for
    hyperparameters that no learner of the benchmark has. ``seeds`` (<= the benchmark's:
    its first ``seeds`` seeds, the same keys as in the full run) and ``rounds`` (<= the
    protocol's) make a smaller run. A learner outside the benchmark that shares a tuned
    hyperparameter with a learner it runs beside is refused (one value per name).
    """
    policies = registry.check_names(tuple(bench.learners) if policies is None
                                    else tuple(policies))
    for what, value, most in (("seeds", seeds, bench.seeds),
                              ("rounds", rounds, bench.protocol["rounds"])):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                  or not 1 <= value <= most):
            raise ValueError(f"{what} must be an integer in [1, {most}] (benchmark "
                             f"{bench.name} has {most} {what}), got {value!r}")
    tuned_fields = {k for name in bench.learners for k in _effective(name, {})}
    values: dict[str, Any] = {}
    for key, value in (hyper or {}).items():
        if key in tuned_fields:
            raise ValueError(f"{_flag(key)}: benchmark {bench.name} fixes the hyperparameters "
                             "of its learners")
        values[key] = value
    owner: dict[str, str] = {}
    for name in policies:
        if name in bench.learners:
            for key, value in _effective(name, bench.learners[name]).items():
                values[key], owner[key] = value, name
    for name in policies:
        if name in bench.learners:
            continue
        for key, default in _effective(name, {}).items():
            if key in owner and values[key] != default:
                raise ValueError(
                    f"--policies: {name} is not a learner of benchmark {bench.name} but "
                    f"shares the hyperparameter {_flag(key)} with {owner[key]}, which it "
                    f"tunes to {values[key]!r}; run {name} without {owner[key]}")
    protocol = bench.protocol
    fields = ("alpha", "epsilon", "alpha0", "p")
    return config_lib.OnlineConfig(
        policies=policies, num_seeds=bench.seeds if seeds is None else seeds,
        rounds=protocol["rounds"] if rounds is None else rounds,
        explore=protocol["explore"], evaluate=protocol["evaluate"],
        eval_poses=protocol["eval_poses"], eval_trials=protocol["eval_trials"],
        fit_steps=protocol["fit_steps"], core_set=protocol["core_set"],
        loss=protocol["loss"], seed=protocol["seed"], backend=protocol["backend"],
        **{k: values[k] for k in fields if k in values},
        hyper=tuple(sorted((k, v) for k, v in values.items() if k not in fields)))


def _flag(field: str) -> str:
    return registry.hyperparameters()[field].metadata.get("flag", field)


def check_theta0(bench: Benchmark, theta0: artifacts.Theta0, flag: str | None = None) -> None:
    """Refuses a θ0 other than the one the benchmark assumes (its ``theta0.sha256`` against
    the θ0's manifest), in one line; ``flag`` names where the θ0 came from (``--theta0
    DIR``), None: the shipped θ0."""
    digest = str(theta0.manifest.get("theta0_sha256", ""))
    if digest != bench.theta0_sha256:
        where = flag or "the shipped θ0"
        raise ValueError(f"{where} (sha256 {digest[:16] or 'unknown'}) is not the θ0 "
                         f"benchmark {bench.name} assumes (sha256 {bench.theta0_sha256[:16]},"
                         f" {bench.path.name}); run it with that θ0")
