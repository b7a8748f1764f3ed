"""One MJX trial program for every object: scenes of one ("uniform") model structure.

MJX derives its collision code from the model's static structure: the geom pairs (from geom
types, ``contype`` / ``conaffinity``, bodies), the collision function of each pair (geom
types, mesh ids, ``condim``) and the shapes of each mesh's convex data (vertices, faces,
edges). A scene per object, built by ``scene.build_scene``, has its own structure (one to
four geoms of types box / sphere / capsule / mesh, meshes of their own sizes), so each object
compiled its own trial program. A uniform scene gives every object the same structure:

* the object is exactly ``UniformShape.parts`` convex **mesh** parts (mesh ids 0..P-1, the
  same geom flags as ``scene.scene_xml`` gives every object geom);
* each part is the convex hull of the exact part (box corners, mesh vertices, a dense
  sampling of the surface of spheres and capsules), reduced by farthest-point subsampling
  to at most ``UniformShape.vertices`` vertices when it has more;
* an object with fewer parts gets inert parts: the largest part shrunk by
  ``INERT_SCALE`` about its vertex mean, so they lie deep inside the object and never touch
  the table or the gripper (their contacts are computed and always inactive);
* MJX's convex data of every part are padded to fixed sizes (``UniformShape.faces``,
  ``.edges``, ``.face_vertices``, ``.vertices``) by repeating their last entry: every
  collision routine of MJX on these data takes a max or a first-index argmax over them, so an
  appended copy never changes a result (``plane_convex`` drops repeated indices, and a copy's
  index comes after its original's);
* the object body keeps the exact scene's mass, centre of mass and inertia (written as its
  ``<inertial>``), so only the collision shape changes;
* the static fields that hold per-object data and that no step reads (the raw mesh arrays,
  used only when ``mjx.put_model`` builds the convex data, and the name table) are replaced
  by fixed values, so all uniform models of one :class:`UniformShape` and one
  ``scene.SceneConfig`` are pytrees of one structure and shapes: one ``jit`` program serves
  them all, and they stack on a leading object axis (:func:`stack_models`).

What may differ between objects (stacked, batched): vertex positions and convex data, geom
positions / orientations / bounds, body masses, inertias and centres of mass, frictions,
``qpos0`` and every other array leaf of ``mjx.Model``. What must be equal: every static field
(geom types and flags, mesh ids, body tree, solver options); :func:`stack_models` checks it.

The native backend stays the reference: ``uniform_scene(model)`` is an ``MjModel`` that
native MuJoCo runs too, so the shape change is measured natively (exact scene against
uniform scene, ``experiments/diagnostics/mjx_one_program.py``) apart from the backend
change (native against MJX on the uniform scene).
"""

from __future__ import annotations

import copy
import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from sern_jax.grasp.world import objects as objects_lib
from sern_jax.grasp.world import scene as scene_lib

__all__ = [
    "INERT_SCALE",
    "MAX_FACE_VERTICES",
    "RESAMPLE_TOLERANCE",
    "UniformShape",
    "part_vertices",
    "hull_distance",
    "uniform_spec",
    "shape_for",
    "general_mass_pattern",
    "uniform_scene",
    "resample_distances",
    "put_uniform",
    "stack_models",
]

INERT_SCALE = 0.01  # inert parts: the largest part shrunk to 1 % about its vertex mean
MAX_FACE_VERTICES = 20  # MJX's most vertices per (merged coplanar) hull face
# The farthest a point of an exact part may lie outside its resampled hull, as a fraction
# of that part's largest distance from its centre. Boxes and hulls of at most ``vertices``
# vertices stay exact; round parts (spheres, capsules) and larger hulls lose their caps
# between the kept vertices (tests/grasp/test_mjx_one_program.py checks the bound).
RESAMPLE_TOLERANCE = 0.15


# The MJX trial program's version (the uniform scenes' structure and the Newton Hessian's
# assembly, sim.make_execute): a change makes MJX runs other runs.
MJX_PROGRAM = "uniform-2"


@dataclasses.dataclass(frozen=True)
class UniformShape:
    """The fixed structure of a uniform scene.

    Attributes:
      parts: convex mesh parts per object (objects with more parts are refused).
      vertices: most vertices per part (hulls with more are subsampled); the padded vertex
        count. ``faces`` (2V - 4) and ``edges`` (3V - 6) bound any hull of V vertices.
    """

    parts: int = 4
    vertices: int = 32

    def __post_init__(self):
        for name, low, high in (("parts", 1, 16), ("vertices", 8, objects_lib.MAX_MESH_VERTICES)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
                raise ValueError(f"UniformShape.{name} must be an int in [{low}, {high}], "
                                 f"got {v!r}")

    @property
    def faces(self) -> int:
        return 2 * self.vertices - 4

    @property
    def edges(self) -> int:
        return 3 * self.vertices - 6

    @property
    def face_vertices(self) -> int:
        return MAX_FACE_VERTICES


# ----------------------------------------------------------------------------- geometry


def _hull_vertices(points: np.ndarray) -> np.ndarray:
    import trimesh

    return np.asarray(trimesh.convex.convex_hull(np.asarray(points, np.float64)).vertices)


def part_vertices(points: np.ndarray, max_vertices: int) -> np.ndarray:
    """The resampled hull of one part: the hull vertices of ``points`` [N, 3], reduced to
    ``max_vertices`` by the deterministic farthest-point subset when there are more."""
    v = _hull_vertices(points)
    if len(v) > max_vertices:
        v = _hull_vertices(objects_lib._farthest_point_subset(v, max_vertices))
    return v


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _surface_samples(kind: str, size, vertices) -> np.ndarray:
    """Points on the exact surface of a part (geom frame): the corners of boxes and meshes
    (the distance to a convex set is convex, so over a polytope it peaks at a corner), a
    dense even sampling of spheres and capsules."""
    if kind in ("box", "mesh"):
        return objects_lib.geom_points(kind, size, vertices)
    r = float(size[0])
    sph = _fibonacci_sphere(2000) * r
    if kind == "sphere":
        return sph
    h = float(size[1])
    ang = np.linspace(0, 2 * math.pi, 64, endpoint=False)
    side = np.stack([np.c_[r * np.cos(ang), r * np.sin(ang), np.full(64, z)]
                     for z in np.linspace(-h, h, 9)]).reshape(-1, 3)
    return np.concatenate([sph[sph[:, 2] >= 0] + [0, 0, h], sph[sph[:, 2] < 0] - [0, 0, h],
                           side])


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distances [N, T] of points p [N, 3] from triangles tri [T, 3, 3]."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    best = np.full((len(p), len(tri)), np.inf)
    n = np.cross(b - a, c - a)
    nn = np.maximum(np.einsum("ij,ij->i", n, n), 1e-300)
    # projection inside the triangle: distance to the plane
    d = p[:, None, :] - a[None]
    t = np.einsum("ntj,tj->nt", d, n) / nn
    q = p[:, None, :] - t[..., None] * n[None]
    inside = np.ones_like(best, bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ntj,tj->nt", np.cross(v - u, q - u[None]), n) >= 0
    plane = np.abs(t) * np.sqrt(nn)
    best = np.where(inside, plane, best)
    for u, v in ((a, b), (b, c), (c, a)):  # the three edges
        e = v - u
        s = np.clip(np.einsum("ntj,tj->nt", p[:, None, :] - u[None], e)
                    / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
        closest = u[None] + s[..., None] * e[None]
        best = np.minimum(best, np.linalg.norm(p[:, None, :] - closest, axis=-1))
    return best


def hull_distance(points: np.ndarray, vertices: np.ndarray) -> float:
    """The farthest any of ``points`` [N, 3] lies outside the convex hull of ``vertices``
    (0 for points inside), metres."""
    import trimesh

    hull = trimesh.convex.convex_hull(np.asarray(vertices, np.float64))
    p = np.asarray(points, np.float64)
    outside = (p @ hull.face_normals.T - np.einsum("ij,ij->i", hull.face_normals,
                                                    hull.triangles[:, 0])).max(1) > 1e-12
    if not outside.any():
        return 0.0
    return float(_point_triangle_distance(p[outside], hull.triangles).min(1).max())


def _object_parts(model: mujoco.MjModel) -> list[tuple]:
    """The object's compiled parts: (kind, size, pos, quat, resample source points) each."""
    ids = scene_lib.scene_ids(model)
    parts = []
    for g in ids.object_geoms:
        kind = scene_lib._GEOM_NAMES.get(int(model.geom_type[g]))
        if kind is None:
            raise ValueError(f"object geom {g} has type {int(model.geom_type[g])}, not one "
                             f"of {objects_lib.GEOM_TYPES}")
        pts = _resample_source(kind, model.geom_size[g], scene_lib._geom_local_points(model, g))
        parts.append((kind, model.geom_size[g].copy(), model.geom_pos[g].copy(),
                      model.geom_quat[g].copy(), pts))
    return parts


def _parts_of_spec(spec: objects_lib.ObjectSpec):
    return [(g.type, np.asarray(g.size, np.float64), np.asarray(g.pos, np.float64),
             np.asarray(g.quat, np.float64),
             _resample_source(g.type, g.size, objects_lib.geom_points(g.type, g.size,
                                                                      g.vertex_array)))
            for g in spec.geoms]


def _resample_source(kind: str, size, points: np.ndarray) -> np.ndarray:
    """The points a part's resampled hull is drawn from: its corners for boxes and meshes,
    a dense sampling of the surface for spheres and capsules (so that the farthest-point
    subset spreads the hull's vertices evenly over the round surface)."""
    return points if kind in ("box", "mesh") else _surface_samples(kind, size, None)


def _uniform_geoms(parts, shape: UniformShape) -> tuple[objects_lib.GeomSpec, ...]:
    if len(parts) > shape.parts:
        raise ValueError(f"the object has {len(parts)} parts, more than "
                         f"UniformShape.parts = {shape.parts}; use a larger parts count")
    geoms, volumes = [], []
    for _kind, _size, pos, quat, pts in parts:
        g = objects_lib._mesh(part_vertices(pts, shape.vertices), pos, quat)
        geoms.append(g)
        volumes.append(g.volume)
    big = geoms[int(np.argmax(volumes))]
    v = big.vertex_array
    centre = v.mean(0)
    inert = objects_lib._mesh(centre + INERT_SCALE * (v - centre), big.pos, big.quat)
    return tuple(geoms) + (inert,) * (shape.parts - len(geoms))


def shape_for(model: mujoco.MjModel) -> UniformShape:
    """The default UniformShape of a scene: 4 parts (every named and sampled object fits),
    or the next power of two of its part count when it has more (decomposed meshes)."""
    n = len(scene_lib.scene_ids(model).object_geoms)
    return UniformShape(parts=max(4, 1 << max(n - 1, 0).bit_length()))


def uniform_spec(spec: objects_lib.ObjectSpec,
                 shape: UniformShape = UniformShape()) -> objects_lib.ObjectSpec:
    """``spec`` as ``shape.parts`` mesh parts (resampled hulls, inert parts appended). Its
    mass is spread by part volume; :func:`uniform_scene` keeps the exact body's inertia."""
    return dataclasses.replace(spec, geoms=_uniform_geoms(_parts_of_spec(spec), shape))


def resample_distances(model: mujoco.MjModel,
                       shape: UniformShape = UniformShape()) -> list[dict]:
    """For each exact part of a scene's object: how far its exact surface lies outside its
    resampled hull, in metres and as a fraction of the part's radius (largest distance of
    its points from their mean)."""
    out = []
    for kind, size, _pos, _quat, pts in _object_parts(model):
        verts = None
        if kind == "mesh":
            verts = pts
        exact = _surface_samples(kind, size, verts)
        d = hull_distance(exact, part_vertices(pts, shape.vertices))
        radius = float(np.linalg.norm(exact - exact.mean(0), axis=1).max())
        out.append({"kind": kind, "distance_m": d, "radius_m": radius,
                    "relative": d / radius})
    return out


# ----------------------------------------------------------------------------- scene


_OPT_FIELDS = ("timestep", "impratio", "tolerance", "ls_tolerance", "noslip_tolerance",
               "gravity", "wind", "density", "viscosity", "o_margin", "o_solref", "o_solimp",
               "o_friction", "integrator", "cone", "jacobian", "solver", "iterations",
               "ls_iterations", "noslip_iterations", "disableflags", "enableflags")


_BODY_FIELDS = ("body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass",
                "body_subtreemass", "body_inertia", "body_invweight0", "body_gravcomp")


def _transplant(exact: mujoco.MjModel, uni: mujoco.MjModel) -> None:
    """Copies into ``uni`` everything of ``exact`` outside the object's geoms: options,
    joints, dofs, actuators, bodies and the other geoms (matched by name), so that a scene
    edited after its build (gains, frictions, masses) keeps its edits."""
    e_ids, u_ids = scene_lib.scene_ids(exact), scene_lib.scene_ids(uni)
    if (exact.nbody, exact.njnt, exact.nv, exact.nu) != (uni.nbody, uni.njnt, uni.nv, uni.nu):
        raise ValueError("the model is not a grasp scene of scene.scene_xml (its bodies, "
                         "joints or actuators differ from the uniform scene's)")
    for name in _OPT_FIELDS:
        value = getattr(exact.opt, name)
        setattr(uni.opt, name, value.copy() if isinstance(value, np.ndarray) else value)
    other = [(mujoco.mj_id2name(exact, mujoco.mjtObj.mjOBJ_GEOM, g), g)
             for g in range(exact.ngeom) if g not in e_ids.object_geoms]
    u_other = [mujoco.mj_name2id(uni, mujoco.mjtObj.mjOBJ_GEOM, n) for n, _ in other]
    if min(u_other, default=0) < 0 or len(u_other) != uni.ngeom - len(u_ids.object_geoms):
        raise ValueError("the model's gripper and table geoms differ from the uniform scene's")
    e_other = [g for _, g in other]
    for name in dir(exact):
        if not (name.startswith(("actuator_", "jnt_", "dof_", "geom_"))
                or name in _BODY_FIELDS):
            continue
        src = getattr(exact, name)
        if not isinstance(src, np.ndarray):
            continue
        dst = getattr(uni, name)
        if name.startswith("geom_"):
            dst[u_other] = src[e_other]
        elif src.shape == dst.shape:
            dst[...] = src
    uni.qpos0[:] = exact.qpos0
    uni.qpos_spring[:] = exact.qpos_spring
    for g in u_ids.object_geoms:  # the object's contact settings, from its first part
        for name in ("geom_friction", "geom_solref", "geom_solimp", "geom_solmix",
                     "geom_priority", "geom_condim", "geom_contype", "geom_conaffinity"):
            getattr(uni, name)[g] = getattr(exact, name)[e_ids.object_geoms[0]]


def uniform_scene(model: mujoco.MjModel,
                  shape: UniformShape = UniformShape()) -> mujoco.MjModel:
    """The uniform scene of a grasp scene (``scene.build_scene``): the same gripper, table,
    settings and initial state, the object as ``shape.parts`` mesh parts with the exact
    body's mass, centre of mass and inertia.

    Raises:
      ValueError: not a grasp scene, or the object has more than ``shape.parts`` parts.
    """
    if not isinstance(model, mujoco.MjModel):
        raise ValueError(f"model must be a mujoco.MjModel, got {type(model).__name__}")
    if not isinstance(shape, UniformShape):
        raise ValueError(f"shape must be a UniformShape, got {type(shape).__name__}")
    ids = scene_lib.scene_ids(model)
    body = ids.object_body
    config = scene_lib.scene_config(model)
    spec = objects_lib.ObjectSpec("uniform", _uniform_geoms(_object_parts(model), shape),
                                  float(model.body_mass[body]))
    inertial = (model.body_ipos[body], model.body_iquat[body], model.body_mass[body],
                model.body_inertia[body])
    uni = mujoco.MjModel.from_xml_string(scene_lib.scene_xml(spec, config, inertial))
    _transplant(model, uni)
    return uni


# ----------------------------------------------------------------------------- mjx models

# Static fields of mjx.Model that hold per-object data no step reads: the raw mesh arrays
# (mjx.put_model turns them into the padded convex data) and the frame flags (MJX always
# composes frames in full). The name table is the same for every uniform scene.
_FREE_STATIC = (
    "nmeshvert", "nmeshnormal", "nmeshtexcoord", "nmeshface", "nmeshgraph", "nmeshpoly",
    "nmeshpolyvert", "nmeshpolymap",
    "mesh_vertadr", "mesh_vertnum", "mesh_faceadr", "mesh_normaladr", "mesh_normalnum",
    "mesh_texcoordadr", "mesh_texcoordnum", "mesh_graphadr", "mesh_vert", "mesh_normal",
    "mesh_face", "mesh_facenormal", "mesh_facetexcoord", "mesh_graph", "mesh_pos",
    "mesh_quat", "mesh_texcoord", "mesh_scale", "mesh_polynum", "mesh_polyadr",
    "mesh_polynormal", "mesh_polyvertadr", "mesh_polyvertnum", "mesh_polyvert",
    "mesh_polymapadr", "mesh_polymapnum", "mesh_polymap", "mesh_bvhadr", "mesh_bvhnum",
    "mesh_octadr", "mesh_octnum", "mesh_pathadr",
    "geom_sameframe", "body_sameframe", "body_simple", "dof_simplenum",
)
_EMPTIED = {"mesh_vert", "mesh_normal", "mesh_face", "mesh_facenormal", "mesh_facetexcoord",
            "mesh_graph", "mesh_texcoord", "mesh_polynormal", "mesh_polyvert", "mesh_polymap"}


def general_mass_pattern(dof_parentid: np.ndarray) -> dict:
    """The sparsity pattern of the mass matrix with no "simple" body: row i holds dof i's
    ancestors and then i. MuJoCo drops the couplings of a body whose inertia sits at its
    frame (a "simple" body: whether it is depends on the exact object), and MJX masks the
    dense mass matrix with the pattern; the general pattern holds every coupling that any
    object can have, and a coupling that is zero stays zero."""
    rows = []
    for i in range(len(dof_parentid)):
        chain, j = [], int(dof_parentid[i])
        while j >= 0:
            chain.append(j)
            j = int(dof_parentid[j])
        rows.append(sorted(chain) + [i])
    nnz = np.array([len(r) for r in rows], np.int32)
    adr = np.concatenate([[0], np.cumsum(nnz)[:-1]]).astype(np.int32)
    return {"nC": int(nnz.sum()), "M_rownnz": nnz, "M_rowadr": adr,
            "M_colind": np.array([c for r in rows for c in r], np.int32)}


def _pad(x: np.ndarray, size: int, axis: int, what: str) -> np.ndarray:
    n = x.shape[axis]
    if n > size:
        raise ValueError(f"a part's convex hull has {n} {what}, more than the uniform {size}")
    widths = [(0, 0)] * x.ndim
    widths[axis] = (0, size - n)
    return np.pad(x, widths, mode="edge")


def _padded_convex(c, shape: UniformShape):
    from mujoco.mjx._src import types as mjx_types

    face = _pad(_pad(np.asarray(c.face), shape.face_vertices, 1, "face vertices"),
                shape.faces, 0, "faces")
    return mjx_types.ConvexMesh(
        vert=jnp.asarray(_pad(np.asarray(c.vert), shape.vertices, 0, "vertices")),
        face=jnp.asarray(face),
        face_normal=jnp.asarray(_pad(np.asarray(c.face_normal), shape.faces, 0, "faces")),
        edge=jnp.asarray(_pad(np.asarray(c.edge), shape.edges, 0, "edges")),
        edge_face_normal=jnp.asarray(_pad(np.asarray(c.edge_face_normal), shape.edges, 0,
                                          "edges")),
    )


def _normalized(mx, shape: UniformShape):
    """``mx`` with padded convex data and the per-object static fields fixed."""
    fields = {f.name for f in dataclasses.fields(mx)}
    values = {}
    for name in _FREE_STATIC:
        if name not in fields:
            continue
        v = getattr(mx, name)
        if isinstance(v, np.ndarray):
            values[name] = (np.zeros((0,) + v.shape[1:], v.dtype) if name in _EMPTIED
                            else np.zeros_like(v))
        elif isinstance(v, (bytes, str)):
            values[name] = type(v)()
        elif isinstance(v, (int, np.integer)):
            values[name] = 0
    pattern = general_mass_pattern(mx.dof_parentid)
    for name, v in pattern.items():
        old = getattr(mx, name)
        values[name] = np.asarray(v, old.dtype) if isinstance(old, np.ndarray) else v
    impl = mx._impl.replace(
        mesh_convex=tuple(_padded_convex(c, shape) for c in mx._impl.mesh_convex),
        geom_rbound_hfield=np.zeros_like(mx._impl.geom_rbound_hfield))  # no height fields
    return mx.replace(_impl=impl, **values)


def put_uniform(model: mujoco.MjModel, shape: UniformShape = UniformShape()):
    """``mjx.put_model`` of a uniform scene (:func:`uniform_scene`), normalized: padded
    convex data and fixed per-object static fields, so that the uniform models of all
    objects (same shape, same scene settings) share one pytree structure."""
    from sern_jax.grasp.world._mjx import mjx

    ids = scene_lib.scene_ids(model)
    if len(ids.object_geoms) != shape.parts or model.nmesh != shape.parts or any(
            model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH for g in ids.object_geoms):
        raise ValueError(f"model is not a uniform scene of {shape} (uniform_scene builds one)")
    dense = copy.copy(model)
    dense.opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE  # MJX: dense mass matrix, always
    return _normalized(mjx.put_model(dense), shape)


def _static_diff(a, b) -> list[str]:
    """Names of the static (non-array-leaf) parts in which two mjx models differ."""
    da, db = jax.tree_util.tree_structure(a), jax.tree_util.tree_structure(b)
    if da == db:
        return []
    out = []
    for f in dataclasses.fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if f.name == "_impl":
            continue
        la = jax.tree_util.tree_leaves(va)
        if jax.tree_util.tree_structure(va) != jax.tree_util.tree_structure(vb):
            out.append(f.name)
        elif not la and not (np.shape(va) == np.shape(vb) and np.array_equal(
                np.asarray(va, dtype=object) if isinstance(va, (bytes, str)) else va,
                np.asarray(vb, dtype=object) if isinstance(vb, (bytes, str)) else vb)):
            out.append(f.name)
    return out or ["_impl"]


def stack_models(models):
    """Stacks uniform mjx models (:func:`put_uniform`) on a new leading object axis.

    Raises:
      ValueError: the models differ in a static field or a leaf shape (other scene
        settings, another UniformShape), naming the first fields that differ.
    """
    models = list(models)
    if not models:
        raise ValueError("no models to stack")
    first = models[0]
    tree = jax.tree_util.tree_structure(first)
    shapes = [np.shape(x) for x in jax.tree_util.tree_leaves(first)]
    for i, m in enumerate(models[1:], 1):
        if jax.tree_util.tree_structure(m) != tree:
            raise ValueError(f"model {i} has another static structure than model 0 "
                             f"(differs in {', '.join(_static_diff(first, m)[:5])})")
        if [np.shape(x) for x in jax.tree_util.tree_leaves(m)] != shapes:
            raise ValueError(f"model {i} has other array shapes than model 0")
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *models)
