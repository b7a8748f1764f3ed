"""The online learning experiment's settings, its learners and its fingerprint.

:class:`OnlineConfig` holds the paper's Section VI setting (``sern grasp learn``'s
defaults); the learners of a run are ``sern_jax.learners`` triples built from it over θ0's
quality network (:func:`make_learner`, :func:`quality_model`); :func:`run_fingerprint` is
what determines a run's results (a run directory made with other settings is refused).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json

import numpy as np

from sern_jax.grasp.model import artifacts
from sern_jax.grasp.model import quality_net as qn
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import sim as sim_lib
from sern_jax.learners import base as lbase
from sern_jax.learners import registry

__all__ = [
    "CHECKPOINT_VERSION",
    "MJX_BATCH",
    "LearnerError",
    "OnlineConfig",
    "check_seed_indices",
    "copies_network",
    "core_data",
    "extend_fingerprint",
    "make_learner",
    "quality_model",
    "run_fingerprint",
    "train_config",
]

MJX_BATCH = 2048  # MJX trials per compiled call: every call of a run has this one shape
CHECKPOINT_VERSION = 5  # bump when the checkpoint's contents change (5: results + rewards,
#                        learner states rebuilt by replaying the updates on resume)

# OnlineConfig fields that are learner hyperparameters (the registry's configs read them)
_HYPER_FIELDS = ("alpha", "epsilon", "alpha0", "p")


@dataclasses.dataclass(frozen=True)
class OnlineConfig:
    """The online learning experiment (defaults: the paper's Section VI setting).

    Attributes:
      policies: learner names (``registry.names()``).
      num_seeds: S independent runs per (object, learner).
      rounds: R rounds of exploration + update + evaluation.
      explore: grasps per exploration phase (paper: 20).
      evaluate: greedy grasps per evaluation phase (paper: 5).
      alpha: SERN's temperature (paper: 0.05).
      epsilon: ε of ε-greedy (paper: 0.1).
      alpha0, p: Algorithm 1's schedule α = α0/ln(T^p) for ``sern_log``.
      hyper: other learners' hyperparameters as sorted (name, value) pairs (fields of their
        registry configs; missing ones take the configs' defaults).
      fit_steps, batch_size, learning_rate: the optax (Adam) update after each exploration.
      loss: ``"bce"`` (default) or ``"l1"`` (the printed Algorithm 1, a negative control).
      core_set: ``"dpp"`` (shipped), ``"random"`` (same size, uniform from D0's sample) or
        ``"none"``.
      eval_poses, eval_trials: the low-variance evaluation (0 poses = off).
      regret_trials: M > 0 turns on regret accounting: every valid candidate of every
        exploration context is simulated M times to choose the best candidate a* (the
        argmax of its frequencies) and M more, independent, times to value every candidate
        (v_a ~ successes / M); each round's pseudo-regret sum_e [v_{a*}(s_e) -
        sum_a pi(a|s_e) v_a(s_e)] is recorded per learner (``stats.oracle_regret``: the
        max and its value from the same trials would add the upward bias of a maximum of
        noisy frequencies). Costly: 2 x 64 x M trials per exploration grasp, shared by the
        learners. 0 = off.
      regret_grasps: g > 0 runs the oracle on the first g exploration grasps of each phase
        only and records (explore / g) x their pseudo-regret: an unbiased estimate of the
        phase's (its grasps are i.i.d.: fresh poses, one learner state per phase) at g /
        explore of the oracle's cost. 0 = every grasp.
      seed: root seed.
      backend: physics backend for trials.
    """

    policies: tuple[str, ...] = ("sern", "egreedy", "greedy")
    num_seeds: int = 5
    rounds: int = 5
    explore: int = 20
    evaluate: int = 5
    alpha: float = 0.05
    epsilon: float = 0.1
    alpha0: float = 1.0
    p: float = 0.3
    fit_steps: int = 40
    batch_size: int = 32
    learning_rate: float = 3e-4
    loss: str = "bce"
    core_set: str = "dpp"
    eval_poses: int = 4
    eval_trials: int = 8
    regret_trials: int = 0
    regret_grasps: int = 0
    seed: int = 0
    backend: str = "native"
    hyper: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "policies", registry.check_names(self.policies, "--policies"))
        known = registry.hyperparameters()
        hyper = dict(self.hyper)
        for k in hyper:
            if k not in known or k in _HYPER_FIELDS:
                raise ValueError(f"hyper: {k!r} is not another learner's hyperparameter; "
                                 f"known: {', '.join(sorted(set(known) - set(_HYPER_FIELDS)))}")
        # canonical: defaults dropped, sorted (the same run has one fingerprint)
        hyper = tuple(sorted((str(k), v) for k, v in hyper.items()
                             if not (type(v) is type(known[k].default)
                                     and v == known[k].default)))
        object.__setattr__(self, "hyper", hyper)
        for name in ("num_seeds", "rounds", "explore", "evaluate", "fit_steps", "batch_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("eval_poses", "eval_trials", "regret_trials", "regret_grasps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        if self.regret_grasps > self.explore:
            raise ValueError(f"regret_grasps must be <= explore ({self.explore}), got "
                             f"{self.regret_grasps}")
        if self.num_seeds * self.rounds * self.explore > 10_000_000:
            raise ValueError("num_seeds x rounds x explore exceeds 10M grasps per object")
        # every registered learner's config is built, so a bad value of any flag is refused
        # (naming its flag) whether or not its learner runs
        for name in registry.names():
            registry.make_config(name, self.hyperparameters())
        if self.core_set not in ("dpp", "random", "none"):
            raise ValueError(f"core_set must be dpp, random or none, got {self.core_set!r}")
        if self.backend not in sim_lib.BACKENDS:
            raise ValueError(f"backend must be one of {sim_lib.BACKENDS}, got {self.backend!r}")
        if not 0 <= int(self.seed) < 2**31:
            raise ValueError(f"seed must be in [0, 2**31), got {self.seed}")
        if self.eval_trials == 0 and self.eval_poses > 0:
            raise ValueError("eval_trials must be >= 1 when eval_poses > 0")
        self.train_config()  # fit_steps, batch_size, learning_rate, loss
        for name in self.policies:  # horizon-dependent settings (sern_log's α)
            registry.make(name, _PROBE_MODEL, self.train_config(), self.learner_config(name))

    @property
    def horizon(self) -> int:
        """T of Algorithm 1's schedule: exploration grasps over the whole run."""
        return self.rounds * self.explore

    def hyperparameters(self) -> dict:
        """Every learner hyperparameter of this run by field name."""
        return {**{k: getattr(self, k) for k in _HYPER_FIELDS}, **dict(self.hyper)}

    def learner_config(self, name: str):
        """Learner ``name``'s registry config with this run's hyperparameters."""
        return registry.make_config(name, self.hyperparameters())

    def train_config(self) -> lbase.TrainConfig:
        return lbase.TrainConfig(horizon=self.horizon, fit_steps=self.fit_steps,
                                 batch_size=self.batch_size,
                                 learning_rate=self.learning_rate, loss=self.loss)

    def fingerprint(self) -> str:
        d = dataclasses.asdict(self)
        if "ensemble_ts" in self.policies:
            # ensemble_ts's layout defaulted to whole networks until 0c123bc made shared heads
            # the default; ``hyper`` drops defaults, so a whole-network run made then and a
            # shared-heads run made now would share a fingerprint and resume into each other.
            # Fingerprint "networks" as absent (those old directories keep theirs) and spell
            # "shared" out.
            hyper = dict(d["hyper"])
            hyper.pop("ensemble_heads", None)
            if self.learner_config("ensemble_ts").ensemble_heads == "shared":
                hyper["ensemble_heads"] = "shared"
            d["hyper"] = tuple(sorted(hyper.items()))
        if not d["hyper"]:
            del d["hyper"]  # runs from before the field keep their fingerprint
        if not d["regret_grasps"]:
            del d["regret_grasps"]
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


class LearnerError(RuntimeError):
    """A learner broke the interface's contract (e.g. chose no grasp while some were valid)."""


# ----------------------------------------------------------------------------- learners


@functools.lru_cache(maxsize=4)
def copies_network(config: qn.QualityNetConfig) -> qn.QualityNetwork:
    """θ0's network as the learner computes it: the same function and parameters, with
    convolutions as im2col matmuls (``qn.make_quality_network(conv="im2col")``), which
    run markedly faster than XLA's convolution when vmapped over the O x S parameter copies
    on CPU. The ask/tell loop uses it too, so both make the same choices."""
    return qn.make_quality_network(config, conv="im2col")


@functools.lru_cache(maxsize=4)
def quality_model(network: qn.QualityNetwork) -> lbase.Model:
    """The quality network as a learner's :class:`~sern_jax.learners.base.Model`
    (:func:`sern_jax.grasp.model.quality_net.learner_model`), one object per network so that
    learners built on it are shared between runs in one process."""
    return qn.learner_model(network)


def _probe_network(params, x):
    return x


_PROBE_MODEL = lbase.Model(_probe_network, _probe_network, _probe_network, _probe_network)


def train_config(config: OnlineConfig) -> lbase.TrainConfig:
    return config.train_config()


@functools.lru_cache(maxsize=64)
def _cached_learner(name, model, train, learner_config) -> lbase.Learner:
    return registry.make(name, model, train, learner_config)


def make_learner(config: OnlineConfig, name: str, model: lbase.Model) -> lbase.Learner:
    """Learner ``name`` of the run (the same object for the same settings: compiles are
    shared between runs in one process)."""
    return _cached_learner(name, model, config.train_config(), config.learner_config(name))


def core_data(kind: str, theta0: artifacts.Theta0) -> lbase.Data:
    """The core set C as the learners' ``Data`` (inputs: crop image, grasp depth)."""
    c = artifacts.core_set_data(kind, theta0)
    return lbase.Data((c.image, c.depth), c.label, c.weight)


# ----------------------------------------------------------------------------- fingerprint


def run_fingerprint(config: OnlineConfig, specs: list[objects_lib.ObjectSpec],
                    theta0) -> str:
    """What determines a run's results: the config, the objects (names and geometry, so
    the same mesh file at another scale is another run), θ0, and the default simulated
    world (``sim.physics_settings()``: a change of the default trial, e.g. 6 N -> 20 N
    fingers, is another run; a non-default world, a subset of the seeds and
    learners from outside the registry are hashed on top by :func:`extend_fingerprint`)."""
    objects = [(s.name, repr(s)) for s in specs]
    text = (f"v{CHECKPOINT_VERSION}" + config.fingerprint() + json.dumps(objects)
            + theta0.fingerprint + json.dumps(sim_lib.physics_settings(), sort_keys=True))
    if config.backend == "mjx":  # MJX trials run on the uniform scenes: their version too
        from sern_jax.grasp.world import uniform

        text += uniform.MJX_PROGRAM
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def extend_fingerprint(fingerprint: str, config: OnlineConfig, seeds: tuple[int, ...],
                       context_config: context_lib.ContextConfig,
                       trial_config: sim_lib.TrialConfig, custom: tuple[str, ...]) -> str:
    """:func:`run_fingerprint` with what else makes another run: a subset (or order) of the
    seeds, a non-default simulated world, learners from outside the registry (``custom``:
    their names). The defaults leave the fingerprint unchanged."""
    if seeds != tuple(range(config.num_seeds)):
        fingerprint = _rehash(fingerprint + "seeds" + repr(seeds))
    if (context_config, trial_config) != (context_lib.ContextConfig(), sim_lib.TrialConfig()):
        fingerprint = _rehash(fingerprint + repr(context_config) + repr(trial_config))
    if custom:
        fingerprint = _rehash(fingerprint + repr(sorted(custom)))
    return fingerprint


def _rehash(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_seed_indices(config: OnlineConfig, seed_indices) -> tuple[int, ...]:
    """The seeds a run runs: ``seed_indices`` (distinct, each in ``0 .. num_seeds - 1``;
    None = all, in order) as a tuple of ints; anything else is a ``ValueError``."""
    seeds = tuple(range(config.num_seeds)) if seed_indices is None else tuple(seed_indices)
    if (not seeds or len(set(seeds)) != len(seeds)
            or not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool)
                       and 0 <= i < config.num_seeds for i in seeds)):
        raise ValueError(f"seed_indices must be distinct integers in 0..{config.num_seeds - 1}"
                         f", got {seed_indices!r}")
    return tuple(int(i) for i in seeds)

