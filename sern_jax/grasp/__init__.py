"""The grasp pipeline (imports mujoco, MJX and, in some modules, flax).

Modules are imported on use (``from sern_jax.grasp import context``), not here, so that
importing the package stays cheap. The path an object takes: ``objects`` (spec) ->
``context.make_context`` / ``make_contexts`` (``scene`` resting pose, ``depth`` image,
``candidates``) -> ``sim`` trials (``GraspSimulator``, or ``make_execute`` to vmap).
"""

__all__ = [
    "artifacts",
    "candidates",
    "context",
    "crops",
    "dataset",
    "depth",
    "depth_native",
    "env",
    "objects",
    "online",
    "pretrain",
    "quality_net",
    "scene",
    "sim",
]
