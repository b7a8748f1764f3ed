"""Pictures of a grasp context: the depth image with its candidates, and MuJoCo renders.

``sern grasp show`` is these functions plus flags and the run directory:

* :func:`draw_candidates`: the overhead depth image with the antipodal candidates drawn as
  parallel jaws (two bars at the contacts joined by the closing axis), coloured by a value in
  [0, 1] such as the simulated success probability (matplotlib, no OpenGL);
* :func:`render_scene`: MuJoCo's own renderer, an oblique view of the table and object, and the
  same view with the gripper posed (open) at a grasp; it needs an OpenGL backend, which
  :func:`use_gl` picks and checks first.

OpenGL and ``import mujoco``. MuJoCo reads ``MUJOCO_GL`` when it is first imported, and with a
backend that cannot load (``MUJOCO_GL=egl`` without a loadable EGL, common on GPU clusters)
``import mujoco`` itself raises. ``sern_jax.grasp`` therefore imports mujoco with OpenGL
disabled (its ``__init__``), so simulation, depth images and learning never depend on
``MUJOCO_GL``; :func:`use_gl` loads the backend only when something is rendered, and says in one
line what to install or which backend to pick when it cannot.
"""

from __future__ import annotations

import importlib
import os
import sys

__all__ = ["GL_BACKENDS", "use_gl", "draw_candidates", "render_scene"]

GL_BACKENDS = ("egl", "osmesa", "glfw")

_GL_HINT = {
    "egl": "install an EGL library (the GPU driver's libEGL, or Mesa's: apt-get install "
           "libegl1 libegl-mesa0), or pick --gl osmesa (apt-get install libosmesa6)",
    "osmesa": "install OSMesa (apt-get install libosmesa6), or pick --gl egl",
    "glfw": "glfw needs a display (X11 or Wayland); on a headless machine pick --gl egl or "
            "--gl osmesa",
}


def use_gl(gl: str | None = None) -> str:
    """Makes MuJoCo's renderer use the OpenGL backend ``gl`` and checks that it works.

    Args:
      gl: ``egl``, ``osmesa`` or ``glfw``; None keeps an already set ``MUJOCO_GL``, else
        takes ``egl`` on Linux (MuJoCo's own default elsewhere).

    Returns:
      the backend in use (``MUJOCO_GL``).

    Raises:
      RuntimeError: one line naming the backend, the error, and what to install or which
        other backend to pick (or to skip rendering).
    """
    if gl is not None:
        if gl not in GL_BACKENDS:
            raise RuntimeError(f"unknown OpenGL backend {gl!r}; choose from "
                               f"{', '.join(GL_BACKENDS)}")
        os.environ["MUJOCO_GL"] = gl
    elif "MUJOCO_GL" not in os.environ and sys.platform.startswith("linux"):
        os.environ["MUJOCO_GL"] = "egl"
    backend = os.environ.get("MUJOCO_GL", "")
    try:
        import sern_jax.grasp  # noqa: F401 - mujoco itself, imported without OpenGL
        try:
            from mujoco.rendering.classic import gl_context
        except ImportError:  # mujoco < 4
            from mujoco import gl_context
        importlib.reload(gl_context)  # reads MUJOCO_GL now; Renderer looks GLContext up here
        context = gl_context.GLContext(1, 1)  # a real context: a backend that cannot load fails
        try:
            context.make_current()
        finally:
            context.free()
    except Exception as exc:  # noqa: BLE001 - PyOpenGL raises ImportError, OSError, AttributeError, ...
        hint = _GL_HINT.get(backend.lower(), f"pick one of {', '.join(GL_BACKENDS)}")
        message = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
        raise RuntimeError(f"MuJoCo cannot render with MUJOCO_GL={backend} ({message}); "
                           f"{hint}; or skip rendering") from None
    return backend


def _colour(prob):
    import matplotlib

    return matplotlib.colormaps["RdYlGn"](prob)


def draw_candidates(path, depth, cands, prob, title, colour_label) -> None:
    """Writes ``path``: the depth image [H, W] with each valid candidate of ``cands``
    (``candidates.Candidates``) drawn as an open parallel jaw, coloured by ``prob`` [K]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7.2, 6.0), dpi=120)
    finite = depth[np.isfinite(depth)]
    im = ax.imshow(depth, cmap="gray_r", vmin=finite.min(), vmax=finite.max())
    cbar_depth = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    cbar_depth.set_label("depth (m)")
    valid = np.asarray(cands.valid)
    ends = np.asarray(cands.endpoints)  # [K, 2, 2] (u, v)
    order = np.argsort(np.where(valid, prob, -1.0))  # best drawn last, on top
    for k in order:
        if not valid[k]:
            continue
        p1, p2 = ends[k]
        axis = p2 - p1
        length = np.linalg.norm(axis)
        if length == 0:
            continue
        axis = axis / length
        perp = np.array([-axis[1], axis[0]])
        colour = _colour(float(prob[k]))
        ax.plot(*np.stack([p1, p2]).T, color=colour, lw=0.9, alpha=0.9)
        for p, out in ((p1, -1.0), (p2, 1.0)):
            jaw = p + out * 1.5 * axis  # the jaw sits just outside its contact
            bar = np.stack([jaw - 2.5 * perp, jaw + 2.5 * perp])
            ax.plot(*bar.T, color=colour, lw=2.2, solid_capstyle="butt")
    sm = matplotlib.cm.ScalarMappable(
        cmap="RdYlGn", norm=matplotlib.colors.Normalize(0, 1)
    )
    cbar = fig.colorbar(sm, ax=ax, fraction=0.046, pad=0.10, location="left")
    cbar.set_label(colour_label)
    # Zoom on the object: everything nearer than the table (the image's farthest depth).
    rows, cols = np.nonzero(depth < finite.max() - 2e-3)
    if rows.size:
        pad = 10
        ax.set_xlim(
            max(cols.min() - pad, 0) - 0.5,
            min(cols.max() + pad, depth.shape[1] - 1) + 0.5,
        )
        ax.set_ylim(
            min(rows.max() + pad, depth.shape[0] - 1) + 0.5,
            max(rows.min() - pad, 0) - 0.5,
        )
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("u (px)  [image right = world +x]")
    ax.set_ylabel("v (px)  [image down = world -y]")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def render_scene(path, model, grasp, title) -> None:
    """Writes ``path``: oblique MuJoCo renders of ``model``'s scene (camera ``view``), and the
    gripper open at ``grasp`` [4] (x, y, z, θ) unless it is None. Call :func:`use_gl` first."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import mujoco
    import numpy as np

    from sern_jax.grasp.world import scene as scene_lib

    ids = scene_lib.scene_ids(model)
    data = scene_lib.initial_data(model)
    option = mujoco.MjvOption()
    option.geomgroup[scene_lib.GROUP_GRIPPER] = (
        0  # the parked gripper would cast a shadow
    )
    renderer = mujoco.Renderer(model, 480, 640)
    try:
        renderer.update_scene(data, camera="view", scene_option=option)
        plain = renderer.render().copy()
        option.geomgroup[scene_lib.GROUP_GRIPPER] = 1
        posed = None
        if grasp is not None:
            x, y, z, theta = (float(v) for v in grasp)
            for adr, v in zip(ids.palm_qpos, (x, y, z + scene_lib.FINGER_DROP, theta)):
                data.qpos[adr] = v
            mujoco.mj_kinematics(model, data)
            renderer.update_scene(data, camera="view", scene_option=option)
            posed = renderer.render().copy()
    finally:
        renderer.close()
    panels = [("scene (camera 'view')", plain)]
    if posed is not None:
        panels.append(("gripper open at the best candidate", posed))
    fig, axes = plt.subplots(1, len(panels), figsize=(6.4 * len(panels), 5.0), dpi=110)
    for ax, (name, img) in zip(np.atleast_1d(axes), panels):
        ax.imshow(img)
        ax.set_title(name, fontsize=9)
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
