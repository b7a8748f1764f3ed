"""``mujoco.mjx``, imported with its import-time notices filtered.

mujoco-mjx 3.17.0 ``print``s "Failed to import warp: ..." (and "... mujoco_warp ...") to
stdout when the optional warp backend is missing; it is not used here. On stdout that notice
breaks commands whose stdout is a contract (``sern bench grasp --json``: one JSON object), and
on stderr it turns every one-line error message into three lines. So every module imports mjx
through this one, which drops those two notices and passes any other import-time output on to
stderr.
"""

import contextlib
import io
import sys

_buffer = io.StringIO()
with contextlib.redirect_stdout(_buffer):
    from mujoco import mjx  # noqa: F401  (re-exported)
for _line in _buffer.getvalue().splitlines():
    if _line and not _line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
        print(_line, file=sys.stderr)

__all__ = ["mjx"]
