"""The wedge family: every member rebuilds from its index, fits the gripper along its length,
and its sloped faces lean as its parameters say."""

import math

import numpy as np
import pytest

from sern_jax.grasp.world import objects
from sern_jax.grasp.world import scene as scene_lib


def test_every_member_builds_from_its_name():
    for name in objects.wedge_names():
        spec = objects.make_object(name)
        assert spec.name == name and spec.category == "wedge"
        assert spec == objects.make_object(name)  # rebuilt the same
        assert objects.MIN_MASS_KG <= spec.mass <= objects.MAX_MASS_KG


def test_members_fit_the_open_gripper_along_their_length():
    opening = scene_lib.SceneConfig().opening
    for i in range(objects.WEDGE_COUNT):
        p = objects.wedge_params(i)
        ext = objects.wedge(i).extents
        assert ext[0] == pytest.approx(p["length"])
        assert p["length"] < opening - 0.005
        assert ext[1] == pytest.approx(p["base_width"]) and ext[2] == pytest.approx(p["height"])


def test_sloped_faces_lean_by_the_base_angle():
    for i in (0, 1, 2, 3, 17):
        p = objects.wedge_params(i)
        v = objects.wedge(i).geoms[0].vertex_array
        base = v[np.isclose(v[:, 2], v[:, 2].min())]
        top = v[np.isclose(v[:, 2], v[:, 2].max())]
        run = base[:, 1].max() - top[:, 1].max()
        angle = math.degrees(math.atan2(p["height"], run))
        assert angle == pytest.approx(p["base_angle"], abs=1e-3)


def test_the_family_mixes_sections_and_grades_the_slope():
    params = [objects.wedge_params(i) for i in range(objects.WEDGE_COUNT)]
    assert {p["section"] for p in params} == {"triangle", "trapezoid"}
    angles = np.array([p["base_angle"] for p in params])
    assert angles.min() < 50 and angles.max() > 70


@pytest.mark.parametrize("name", ["wedge_64", "wedge_-1", "wedge_01", "wedge_x"])
def test_names_outside_the_family_are_refused(name):
    with pytest.raises(ValueError, match="unknown object"):
        objects.make_object(name)
