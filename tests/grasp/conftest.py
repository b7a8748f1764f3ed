"""Session fixtures for the grasp tests: one scene, one simulator per backend.

MJX programs compile once per session (20-80 s on 2 CPU cores): every MJX test uses
the ``mjx_sim`` fixture at batch ``MJX_BATCH`` so that they share one compiled program.
"""

import jax
import numpy as np
import pytest

from sern_jax.grasp.world import objects, scene, sim

MJX_BATCH = 8


@pytest.fixture(scope="session")
def box_model():
    return scene.build_scene(objects.make_object("small_box"), seed=0)


@pytest.fixture(scope="session")
def centred_grasp(box_model):
    """The grasp across the small box's narrowest horizontal side, at its centre."""
    return scene.centred_grasp(box_model)


@pytest.fixture(scope="session")
def native_sim(box_model):
    return sim.GraspSimulator(box_model, "native", num_threads=2)


@pytest.fixture(scope="session")
def mjx_sim(box_model):
    return sim.GraspSimulator(box_model, "mjx", mjx_shape=None)  # the scene's own program


@pytest.fixture(scope="session")
def paired_trials(box_model, centred_grasp):
    """MJX_BATCH grasps (centred, shifted 5-20 mm, far away) with random noise."""
    offsets = np.array([[0, 0, 0, 0], [0.005, 0, 0, 0.2], [0, 0.01, 0, -0.3],
                        [0.015, 0.0, 0, 0.5], [0.02, 0.02, 0, 1.0], [0.1, 0, 0, 0],
                        [0, 0, 0.02, 0], [-0.01, 0.005, -0.01, 0.7]])
    grasps = centred_grasp + offsets
    noise = sim.sample_noise(jax.random.key(11), MJX_BATCH)
    return grasps, noise


# ----------------------------------------------------------------------------- learning
# Shared by test_dataset / test_pretrain / test_online / test_learn_cli. Tiny sizes: every
# compiled function (crops, the batched choose / fit of online.run) compiles once per session.

TINY_DATASET = dict(seed=0, num_objects=2, poses_per_object=2, objects_per_shard=1)
CORE_K = 6


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A finished 2-object x 2-pose D0 (one shard per object): (config, directory)."""
    from sern_jax.grasp.model import dataset

    config = dataset.DatasetConfig(**TINY_DATASET)
    out = tmp_path_factory.mktemp("d0")
    dataset.generate(config, out, progress=False, log=lambda *_: None)
    return config, out


@pytest.fixture(scope="session")
def tiny_theta0():
    """A θ0 made in the test: randomly initialised network and a random core set."""
    return make_tiny_theta0()


def make_tiny_theta0():
    """The ``tiny_theta0`` fixture's θ0 (also what tests/grasp/data/make_learn_reference.py
    runs, so the reference and the test start from one θ0)."""
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.model import quality_net as qn

    network = qn.make_quality_network()
    params = network.init(jax.random.key(0))
    s = network.config.crop_size
    rng = np.random.default_rng(0)
    core = {}
    for kind in ("dpp", "random"):
        core[f"{kind}_image"] = rng.normal(0.0, 0.01, (CORE_K, s, s)).astype(np.float32)
        core[f"{kind}_depth"] = rng.uniform(0.55, 0.6, CORE_K).astype(np.float32)
        core[f"{kind}_label"] = (rng.random(CORE_K) < 0.5).astype(np.float32)
        core[f"{kind}_index"] = np.arange(CORE_K)
    return artifacts.Theta0(network, params, core, manifest={}, fingerprint="test",
                            screen=None)
