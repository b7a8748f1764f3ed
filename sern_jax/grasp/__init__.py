"""The grasp pipeline (imports mujoco, MJX and, in some modules, flax).

Modules are imported on use (``from sern_jax.grasp import context``), not here, so that
importing the package stays cheap. The path an object takes: ``objects`` (spec) ->
``context.make_context`` / ``make_contexts`` (``scene`` resting pose, ``depth`` image,
``candidates``) -> ``sim`` trials (``GraspSimulator``, or ``make_execute`` to vmap).

Importing this package imports mujoco with OpenGL disabled (``MUJOCO_GL=disable`` for the
import, the user's value restored after): MuJoCo reads ``MUJOCO_GL`` at import, and a backend
that cannot load (``MUJOCO_GL=egl`` without a loadable EGL) would make ``import mujoco`` raise
in commands that render nothing. Rendering loads its backend when it is asked for
(``pictures.use_gl``).
"""

import pkgutil as _pkgutil

# the modules that exist (``from sern_jax.grasp import *`` imports them all)
__all__ = sorted(m.name for m in _pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


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
