"""Session fixtures for the grasp tests: one scene, one simulator per backend.

MJX programs compile once per session (20-80 s on 2 CPU cores): every MJX test uses
the ``mjx_sim`` fixture at batch ``MJX_BATCH`` so that they share one compiled program.
"""

import jax
import numpy as np
import pytest

from sern_jax.grasp import objects, scene, sim

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
    return sim.GraspSimulator(box_model, "mjx")


@pytest.fixture(scope="session")
def paired_trials(box_model, centred_grasp):
    """MJX_BATCH grasps (centred, shifted 5-20 mm, far away) with random noise."""
    offsets = np.array([[0, 0, 0, 0], [0.005, 0, 0, 0.2], [0, 0.01, 0, -0.3],
                        [0.015, 0.0, 0, 0.5], [0.02, 0.02, 0, 1.0], [0.1, 0, 0, 0],
                        [0, 0, 0.02, 0], [-0.01, 0.005, -0.01, 0.7]])
    grasps = centred_grasp + offsets
    noise = sim.sample_noise(jax.random.key(11), MJX_BATCH)
    return grasps, noise
