"""The grasp world: objects -> scene (resting pose) -> depth -> candidates -> context, and the
grasp trial itself (``sim``: native MuJoCo and MJX backends)."""
