"""Tests for sern_jax.grasp.world.objects: named, hard and sampled objects; mesh import."""

import numpy as np
import pytest
import trimesh

from sern_jax.grasp.world import objects


@pytest.mark.parametrize("name", objects.object_names())
def test_named_objects_are_sane(name):
    spec = objects.make_object(name)
    assert spec.name == name
    ext = np.asarray(spec.extents)
    assert 0.01 <= ext.min() and ext.max() <= 0.105, ext
    # solid-steel parts (7.85 g/cm³) may exceed the population's 500 g, up to 600 g
    top = 0.6 if name.endswith("_steel") else objects.MAX_MASS_KG
    assert objects.MIN_MASS_KG <= spec.mass <= top
    for g in spec.geoms:
        assert g.type in ("box", "sphere", "capsule", "mesh")
        assert len(g.vertices) <= objects.MAX_MESH_VERTICES
    assert spec.volume > 0


def test_hard_set_is_complete():
    hard = objects.hard_object_names()
    for name in ("triangular_prism", "round_stapler", "tilted_mouse", "slim_bottle",
                 "bracket", "pipe_tee"):
        assert name in hard
        assert objects.make_object(name).category == "hard"
    # The triangular prism has a triangular cross-section: 6 vertices.
    assert len(objects.make_object("triangular_prism").geoms[0].vertices) == 6


def test_unknown_name_raises_with_name():
    with pytest.raises(ValueError, match="no_such_thing"):
        objects.make_object("no_such_thing")


def test_population_is_seeded_and_in_range():
    a = objects.sample_population(3, 24)
    b = objects.sample_population(3, 24)
    c = objects.sample_population(4, 24)
    assert a == b
    assert a != c
    kinds = {o.kind for o in a}
    assert len(kinds) >= 5  # a mix of families, not one shape
    for o in a:
        ext = np.asarray(o.extents)
        assert ext.max() <= 0.105 and ext.min() >= 0.015, (o.name, ext)
        assert objects.MIN_MASS_KG * 0.999 <= o.mass <= objects.MAX_MASS_KG * 1.001
    # Sample i of the population does not depend on how many were drawn.
    assert objects.sample_population(3, 5) == a[:5]


def test_population_members_resolve_by_name():
    pop = objects.sample_population(3, 12)
    for o in pop:
        assert objects.resolve_object(o.name) == o
    # Same seed and index, another kind: not that member, and the error says which it is.
    wrong = next(k for k in objects.POPULATION_KINDS if k != pop[0].kind)
    with pytest.raises(ValueError, match=pop[0].name):
        objects.resolve_object(f"{wrong}_3_0")
    with pytest.raises(ValueError, match="blob_3_0"):
        objects.resolve_object("blob_3_0")


def test_sample_object_rejects_bad_kind():
    with pytest.raises(ValueError, match="blob"):
        objects.sample_object(0, kinds=("box", "blob"))


def test_mesh_import_cube_obj(tmp_path):
    path = tmp_path / "cube.obj"
    trimesh.creation.box((40.0, 40.0, 40.0)).export(path)  # millimetres
    spec = objects.load_mesh(path)
    assert spec.category == "mesh" and spec.name == "mesh:cube"
    np.testing.assert_allclose(spec.extents, (0.04, 0.04, 0.04), atol=1e-6)
    assert len(spec.geoms) == 1 and spec.geoms[0].type == "mesh"
    assert len(spec.geoms[0].vertices) == 8
    np.testing.assert_allclose(spec.volume, 0.04**3, rtol=1e-6)
    # Explicit units give the same object; resolve_object accepts the path.
    assert objects.load_mesh(path, units="mm").extents == spec.extents
    assert objects.resolve_object(str(path)).extents == spec.extents


def test_mesh_hull_is_reduced_to_max_vertices(tmp_path):
    path = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=0.03).export(path)
    spec = objects.load_mesh(path, max_vertices=24)
    assert len(spec.geoms[0].vertices) <= 24
    assert 0.05 <= max(spec.extents) <= 0.061


def test_bad_meshes_raise_clearly(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        objects.load_mesh(tmp_path / "missing.obj")
    with pytest.raises(ValueError, match=r"\.obj or \.stl"):
        objects.load_mesh(tmp_path / "thing.ply")
    garbage = tmp_path / "garbage.obj"
    garbage.write_text("this is not a mesh\n")
    with pytest.raises(ValueError):
        objects.load_mesh(garbage)
    open_box = trimesh.creation.box((0.04, 0.04, 0.04))
    open_box.update_faces(np.arange(len(open_box.faces)) != 0)  # drop one triangle
    open_path = tmp_path / "open.obj"
    open_box.export(open_path)
    with pytest.raises(ValueError, match="watertight"):  # open meshes load by default
        objects.load_mesh(open_path, require_watertight=True)
    huge = tmp_path / "huge.stl"
    trimesh.creation.box((40.0, 40.0, 40.0)).export(huge)
    with pytest.raises(ValueError, match="absurd size"):
        objects.load_mesh(huge, units="m")  # a 40 m cube
    with pytest.raises(ValueError, match="absurd size"):
        objects.load_mesh(_write_box(tmp_path / "tiny.stl", 1e-5), units="auto")
    flat = tmp_path / "flat.obj"
    trimesh.creation.box((0.05, 0.05, 0.0002)).export(flat)
    with pytest.raises(ValueError, match="flat"):
        objects.load_mesh(flat, units="m")
    with pytest.raises(ValueError, match="units"):
        objects.load_mesh(huge, units="inch")


def _write_box(path, edge):
    trimesh.creation.box((edge, edge, edge)).export(path)
    return path
