"""Algorithm 1 for a real robot loop: ``ask`` for a grasp, execute it, ``tell`` the reward.

Any registered learner (``sern_jax.learners``) drives it, as one (object, seed) copy of the
batched run (:func:`sern_jax.grasp.online.driver.run`) with the same keys and the same learner
state: given the same depth images it asks for the same grasps and, told the same rewards,
makes the same updates (tests/grasp/test_asktell.py drives both with the simulator, for
every registered learner). After every ``config.explore`` tells the learner's ``update``
runs on the phase's (crops, actions, rewards).
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.infra import io
from sern_jax.core import policies as pol
from sern_jax.grasp.model import artifacts
from sern_jax.grasp.online import checkpoint, step
from sern_jax.grasp.online import config as config_lib
from sern_jax.grasp.online import keys as keys_lib
from sern_jax.grasp.world import candidates as cand_lib
from sern_jax.grasp.world import context as context_lib
from sern_jax.grasp.world import crops as crops_lib
from sern_jax.grasp.world import depth as depth_lib
from sern_jax.learners import base as lbase

__all__ = ["AskTell", "AskTellState"]


class AskTellState(NamedTuple):
    """Everything a robot loop must keep between grasps (save it with :meth:`AskTell.save`)."""

    learner: lbase.LearnerState  # the learner's state (θ, optimiser, D ∪ C, extra)
    phase_image: np.ndarray  # [E, S, S] crops of this phase's grasps (rows < grasp_index)
    phase_depth: np.ndarray  # [E] their grasp depths
    phase_action: np.ndarray  # [E] int32 chosen slots (NO_ARM: nothing was valid)
    phase_reward: np.ndarray  # [E] float32 rewards told
    round_index: int  # 1-based round of the next grasp
    grasp_index: int  # grasps told in this round
    pending: tuple | None  # (slot, crop image [S, S], crop depth []) of the last ask


class AskTell:
    """One learner copy for a robot loop.

    Args:
      config: the experiment settings (rounds, explore, the learners' hyperparameters, fit).
      policy: a registered learner name (``registry.names()``).
      object_name: the name whose CRC32 keys the streams (as in ``driver.run``).
      seed_index: which seed of ``driver.run`` this learner is.
      theta0: the pretrained network (default: the shipped one).
      learner: a Learner to use instead of the registered ``policy`` (as ``driver.run``'s
        ``learners``).
    """

    def __init__(self, config: config_lib.OnlineConfig, policy: str = "sern",
                 object_name: str = "object", seed_index: int = 0,
                 theta0: artifacts.Theta0 | None = None, learner: lbase.Learner | None = None):
        if learner is None:
            from sern_jax.learners import registry

            registry.check_names((policy,), "policy")
        if seed_index < 0:
            raise ValueError(f"seed_index must be >= 0, got {seed_index}")
        self.config, self.policy = config, policy
        self.theta0 = theta0 or artifacts.load_theta0()
        network = config_lib.copies_network(self.theta0.network.config)
        self.model = config_lib.quality_model(network)
        self.learner = learner or config_lib.make_learner(config, policy, self.model)
        self.key_os = keys_lib.object_key(jax.random.key(config.seed), object_name, seed_index)
        self.core = config_lib.core_data(config.core_set, self.theta0)
        self.context_config = context_lib.ContextConfig()
        self.crop_config = crops_lib.CropConfig()
        self._crops = jax.jit(lambda d, c: crops_lib.extract_batch(d, c, self.crop_config))
        self._init = jax.jit(self.learner.init)
        self._act = jax.jit(self.learner.act)
        self._update = jax.jit(self.learner.update)
        predict = step.predict_fn(self.learner, self.model)
        self._greedy = jax.jit(lambda state, obs: pol.sample_icdf(
            obs.u, pol.greedy_probs(predict(state, obs), mask=obs.valid), mask=obs.valid))
        self._sample = jax.jit(lambda k, d, p: cand_lib.sample(
            self.context_config.candidates, k, d, p))

    def init(self) -> AskTellState:
        """θ0 (the learner's init with the batched run's key), an empty D, round 1."""
        key = keys_lib.stream(self.key_os, keys_lib.INIT, 0)
        state = self._init(key, self.theta0.params, self.core)
        return AskTellState(state, *self._empty_phase(), 1, 0, None)

    def _empty_phase(self):
        e, s = self.config.explore, self.crop_config.crop_size
        return (np.zeros((e, s, s), np.float32), np.zeros(e, np.float32),
                np.full(e, pol.NO_ARM, np.int32), np.zeros(e, np.float32))

    def candidates(self, state: AskTellState, depth_image, camera=None):
        """The 64 candidates the learner samples on ``depth_image`` for its next grasp (the
        same key as the batched run's context of that grasp)."""
        camera = camera if camera is not None else depth_lib.overhead_params(
            self.context_config.camera)
        key_ctx = jax.random.fold_in(
            keys_lib.stream(self.key_os, keys_lib.EXPLORE_CONTEXT, state.round_index),
            state.grasp_index)
        key = jax.random.fold_in(key_ctx, context_lib.CANDIDATE_STREAM)
        return jax.tree.map(np.asarray, self._sample(key, jnp.asarray(depth_image), camera))

    def _obs(self, depth_image, cands, u, t):
        batch = jax.tree.map(lambda x: jnp.asarray(x)[None], cands)
        crops = self._crops(jnp.asarray(depth_image, jnp.float32)[None], batch)
        obs = lbase.Obs((crops.image[0], crops.depth[0]), jnp.asarray(cands.valid, bool),
                        jnp.float32(u), jnp.int32(t))
        return obs, crops

    def ask(self, state: AskTellState, depth_image, candidates=None, camera=None):
        """The grasp to try on ``depth_image`` [H, W] (planar depth, metres).

        Returns:
          (grasp [4] (x, y, z, θ) world frame, state); grasp is None when no candidate is
          valid (nothing to try: take another image).
        """
        if state.round_index > self.config.rounds:
            raise ValueError(f"all {self.config.rounds} rounds are done")
        if state.pending is not None:
            raise ValueError("tell() the reward of the last grasp before asking again")
        depth_image = np.asarray(depth_image, np.float32)
        if depth_image.ndim != 2 or not np.all(np.isfinite(depth_image)):
            raise ValueError(f"depth_image must be a finite [H, W] array, got shape "
                             f"{depth_image.shape}")
        cands = candidates if candidates is not None else self.candidates(
            state, depth_image, camera)
        r, e = state.round_index, state.grasp_index
        u = jax.random.uniform(keys_lib.stream(self.key_os, keys_lib.POLICY_UNIFORM, r),
                               (self.config.explore,))[e]
        obs, crops = self._obs(depth_image, cands, u, (r - 1) * self.config.explore + e)
        key = jax.random.fold_in(keys_lib.stream(self.key_os, keys_lib.ACT, r), e)
        action, _, _ = self._act(key, state.learner, obs)
        slot = int(action)
        valid = np.asarray(cands.valid, bool)
        if not 0 <= slot < len(valid) or not valid[slot]:
            if valid.any() or slot != pol.NO_ARM:
                raise config_lib.LearnerError(
                    f"learner {self.policy!r} returned no valid grasp (slot {slot}) while "
                    f"{int(valid.sum())} candidates were valid")
            # No valid candidate: this grasp slot passes with nothing stored, exactly as in
            # the batched run (action NO_ARM, weight 0), so the two stay in step.
            return None, self._advance(state, (0, np.asarray(crops.image[0, 0]),
                                               float(crops.depth[0, 0])), pol.NO_ARM, 0.0)
        pending = (slot, np.asarray(crops.image[0, slot]), float(crops.depth[0, slot]))
        return np.asarray(cands.grasps[slot]), state._replace(pending=pending)

    def tell(self, state: AskTellState, grasp, reward) -> AskTellState:
        """Stores (crop, reward) of the asked grasp; updates after each round's last one."""
        if state.pending is None:
            raise ValueError("tell() without a pending ask()")
        if reward not in (0, 1, 0.0, 1.0, True, False):
            raise ValueError(f"reward must be 0 or 1, got {reward!r}")
        return self._advance(state, state.pending, state.pending[0], float(reward))

    def _advance(self, state: AskTellState, stored, action: int, reward: float) -> AskTellState:
        """Stores this grasp's row of the phase, moves to the next grasp, and runs the
        learner's update after the round's last one."""
        e = state.grasp_index
        image, depth, acts, rewards = (np.array(a) for a in (
            state.phase_image, state.phase_depth, state.phase_action, state.phase_reward))
        image[e], depth[e] = stored[1], stored[2]
        acts[e], rewards[e] = action, reward
        state = state._replace(phase_image=image, phase_depth=depth, phase_action=acts,
                               phase_reward=rewards, pending=None, grasp_index=e + 1)
        if state.grasp_index == self.config.explore:
            key = keys_lib.stream(self.key_os, keys_lib.FIT, state.round_index)
            batch = lbase.Batch((jnp.asarray(image), jnp.asarray(depth)), jnp.asarray(acts),
                                jnp.asarray(rewards))
            state = AskTellState(self._update(key, state.learner, batch), *self._empty_phase(),
                                 state.round_index + 1, 0, None)
        return state

    def best(self, state: AskTellState, depth_image, candidates=None, camera=None):
        """The greedy grasp (evaluation: no exploration, nothing stored)."""
        cands = candidates if candidates is not None else self.candidates(
            state, depth_image, camera)
        obs, _ = self._obs(depth_image, cands, 0.0, 0)
        slot = int(self._greedy(state.learner, obs))
        return None if slot < 0 else np.asarray(cands.grasps[slot])

    def identity(self) -> str:
        """What a saved state belongs to: config, learner, object/seed keys and θ0."""
        text = "|".join([self.config.fingerprint(), self.policy,
                         str(jax.random.key_data(self.key_os).tolist()),
                         self.theta0.fingerprint])
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def save(self, state: AskTellState, path: str | Path) -> None:
        """Writes the state to ``path`` (.npz, atomically), tagged with :meth:`identity`."""
        arrays = checkpoint.state_arrays(state.learner, "L_", self.config.horizon)
        arrays.update(phase_image=state.phase_image, phase_depth=state.phase_depth,
                      phase_action=state.phase_action, phase_reward=state.phase_reward)
        if state.pending is not None:
            arrays.update(pending_slot=np.asarray(state.pending[0]),
                          pending_image=state.pending[1], pending_depth=np.asarray(state.pending[2]))
        io.save_npz(path, round_index=np.asarray(state.round_index),
                    grasp_index=np.asarray(state.grasp_index),
                    identity=np.asarray(self.identity()), **arrays)

    def load(self, path: str | Path) -> AskTellState:
        """Reads a state written by :meth:`save` (verified: a damaged file is an error)."""
        saved = io.load_npz(path)
        if str(saved.get("identity", "")) != self.identity():
            raise ValueError(f"{path} was saved by a learner with another config, policy, "
                             "object, seed or θ0; make the learner with the settings it was "
                             "saved with")
        template = self.init()
        learner = checkpoint.state_from_arrays(saved, "L_", template.learner, self.config.horizon)
        pending = None
        if "pending_slot" in saved:
            pending = (int(saved["pending_slot"]), saved["pending_image"],
                       float(saved["pending_depth"]))
        return AskTellState(learner, saved["phase_image"], saved["phase_depth"],
                            saved["phase_action"], saved["phase_reward"],
                            int(saved["round_index"]), int(saved["grasp_index"]), pending)
