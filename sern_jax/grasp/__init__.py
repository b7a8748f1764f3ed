"""The grasp pipeline (imports mujoco, MJX and, in some modules, flax).

Three subpackages, imported on use (``from sern_jax.grasp.world import context``), not here, so
that importing the package stays cheap:

* ``world``: ``objects`` (spec) -> ``context.make_context`` / ``make_contexts`` (``scene``
  resting pose, ``depth`` image, ``candidates``) -> ``sim`` trials (``GraspSimulator``, or
  ``make_execute`` to vmap);
* ``model``: crops, the quality network, D0, θ0 and the shipped artifacts;
* ``online``: Algorithm 1 over objects x learners x seeds (``step``, ``driver``), the
  ask/tell loop.

Importing this package imports mujoco with OpenGL disabled (``MUJOCO_GL=disable`` for the
import, the user's value restored after): MuJoCo reads ``MUJOCO_GL`` at import, and a backend
that cannot load (``MUJOCO_GL=egl`` without a loadable EGL) would make ``import mujoco`` raise
in commands that render nothing. Rendering loads its backend when it is asked for
(``pictures.use_gl``).
"""

__all__ = ["model", "online", "world"]


def _import_mujoco_without_gl() -> None:
    import os
    import sys

    if "mujoco" in sys.modules:
        return
    saved = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco  # noqa: F401
    except ImportError:
        pass  # the modules that need mujoco say so when they import it
    finally:
        if saved is None:
            os.environ.pop("MUJOCO_GL", None)
        else:
            os.environ["MUJOCO_GL"] = saved


_import_mujoco_without_gl()
