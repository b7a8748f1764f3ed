"""Putting the seed axis on a device mesh.

Seeds are independent, so sharding the seed axis needs no communication: each device runs its
slice of ``vmap(run)`` and results are identical to the single-device run (seed ``i`` always
uses ``fold_in(root, i)``). Multi-host: call ``jax.distributed.initialize()`` first; the mesh
then spans ``jax.devices()`` of all hosts.
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["SEED_AXIS", "seed_mesh"]

SEED_AXIS = "seeds"


def seed_mesh(num_devices: int | None = None) -> jax.sharding.Mesh:
    """A one-axis mesh named ``"seeds"`` over the first ``num_devices`` devices (all if None).

    The axis is ``Auto``-typed, so jitted code needs no sharding annotations inside.
    """
    devices = jax.devices()
    if num_devices is not None:
        if num_devices < 1 or num_devices > len(devices):
            raise ValueError(
                f"num_devices must lie in [1, {len(devices)}] (devices visible: "
                f"{len(devices)}), got {num_devices}"
            )
        devices = devices[:num_devices]
    return jax.sharding.Mesh(np.asarray(devices), (SEED_AXIS,),
                             axis_types=(jax.sharding.AxisType.Auto,))
