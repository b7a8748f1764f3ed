"""``mujoco.mjx``, imported with its import-time notices sent to stderr.

mujoco-mjx 3.17.0 ``print``s "Failed to import warp: ..." to stdout when the optional warp
backend is missing (it is not used here). On stdout that notice breaks commands whose stdout is
a contract, such as ``sern bench grasp --json`` (one JSON object), so every module imports mjx
through this one.
"""

import contextlib
import sys

with contextlib.redirect_stdout(sys.stderr):
    from mujoco import mjx  # noqa: F401  (re-exported)

__all__ = ["mjx"]
