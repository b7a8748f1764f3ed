"""The learners by name: what ``sern grasp learn --policies`` (and any runner) accepts.

Each entry is a factory ``make(model, train, config) -> Learner`` and its hyperparameter
dataclass, whose fields carry their CLI flag and help in ``metadata``; a hyperparameter
shared by several learners (one name) is one flag. Adding a learner = one module in this
folder + one line in ``LEARNERS`` (docs/EXTENDING.md, "Add a learner").
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping, NamedTuple

from sern_jax.learners import (base, decaying, egreedy, ensemble, greedy, neural_linear,
                               neural_ucb, normalized, sern)

__all__ = ["LearnerSpec", "LEARNERS", "names", "check_names", "hyperparameters",
           "make_config", "make"]


class LearnerSpec(NamedTuple):
    make: Callable[[base.Model, base.TrainConfig, Any], base.Learner]
    config: type  # frozen dataclass of hyperparameters (fields' metadata: flag, help)
    summary: str  # one line for --help and the docs


LEARNERS: dict[str, LearnerSpec] = {
    "sern": LearnerSpec(sern.sern, sern.SernConfig, "softmax(r̂/α), fixed α (--alpha)"),
    "sern_log": LearnerSpec(sern.sern_log, sern.SernLogConfig,
                            "softmax(r̂/α), Algorithm 1's α = α0/ln(T^p) (--alpha0, --p)"),
    "egreedy": LearnerSpec(egreedy.egreedy, egreedy.EGreedyConfig,
                           "ε-greedy on r̂ (--epsilon)"),
    "greedy": LearnerSpec(greedy.greedy, greedy.GreedyConfig, "argmax r̂"),
    # the baselines: one module each, defaults from their papers
    "neural_linucb": LearnerSpec(
        neural_linear.neural_linucb, neural_linear.NeuralLinUCBConfig,
        "Neural-Linear UCB on last-layer features (--lambda-prior, --a0, --b0, --ucb-width)"),
    "neural_lints": LearnerSpec(
        neural_linear.neural_lints, neural_linear.NeuralLinTSConfig,
        "Neural-Linear Thompson sampling, Riquelme et al. 2018 (--lambda-prior, --a0, --b0)"),
    "ensemble_ts": LearnerSpec(
        ensemble.ensemble_ts, ensemble.EnsembleConfig,
        "bootstrapped-ensemble Thompson sampling (--ensemble-size, --bootstrap, "
        "--bootstrap-p, --ensemble-heads)"),
    "neural_ucb": LearnerSpec(neural_ucb.neural_ucb, neural_ucb.NeuralUCBConfig,
                              "NeuralUCB, diagonal Z, Zhou et al. 2020 (--ucb-lambda, --nu)"),
    "normalized": LearnerSpec(normalized.normalized, normalized.NormalizedConfig,
                              "π ∝ r̂ over the valid candidates (the paper's [13])"),
    "egreedy_decay": LearnerSpec(decaying.egreedy_decay, decaying.EGreedyDecayConfig,
                                 "ε-greedy, ε_t = min(1, ε0/t) (--decay-epsilon0)"),
    "sern_decay": LearnerSpec(decaying.sern_decay, decaying.SernDecayConfig,
                              "softmax, α_t = α0/log2(1 + t) (--decay-alpha0)"),
}


def names() -> tuple[str, ...]:
    return tuple(LEARNERS)


def check_names(chosen, flag: str = "--policies") -> tuple[str, ...]:
    """``chosen`` as a tuple, or a one-line ``ValueError`` naming ``flag``: not empty, no
    repeats, every name registered."""
    chosen = tuple(chosen)
    if not chosen:
        raise ValueError(f"{flag} must name at least one learner; choose from "
                         f"{', '.join(LEARNERS)}")
    for name in chosen:
        if name not in LEARNERS:
            raise ValueError(f"{flag}: unknown policy {name!r}; choose from "
                             f"{', '.join(LEARNERS)}")
    if len(set(chosen)) != len(chosen):
        raise ValueError(f"{flag}: policies must not repeat, got {','.join(chosen)}")
    return chosen


def hyperparameters() -> dict[str, dataclasses.Field]:
    """Every registered learner's hyperparameter fields by name (one per name: learners
    sharing a name share its flag)."""
    out: dict[str, dataclasses.Field] = {}
    for spec in LEARNERS.values():
        for f in dataclasses.fields(spec.config):
            seen = out.get(f.name)
            if seen is not None and seen.metadata.get("flag") != f.metadata.get("flag"):
                raise TypeError(f"hyperparameter {f.name!r} has two flags")
            out.setdefault(f.name, f)
    return out


def make_config(name: str, values: Mapping[str, Any] | None = None):
    """Learner ``name``'s config from ``values`` (field name -> value; missing fields take
    their defaults, other names are ignored). Bad values: a ``ValueError`` naming the flag."""
    spec = LEARNERS[check_names((name,))[0]]
    values = values or {}
    return spec.config(**{f.name: values[f.name] for f in dataclasses.fields(spec.config)
                          if f.name in values})


def make(name: str, model: base.Model, train: base.TrainConfig, config=None) -> base.Learner:
    """The learner ``name`` over ``model`` (``config``: its dataclass, or a mapping of
    hyperparameters, or None for the defaults)."""
    if config is None or isinstance(config, Mapping):
        config = make_config(name, config)
    spec = LEARNERS[check_names((name,))[0]]
    if not isinstance(config, spec.config):
        raise TypeError(f"{name} takes a {spec.config.__name__}, got {type(config).__name__}")
    return spec.make(model, train, config)
