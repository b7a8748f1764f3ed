"""The ``sern`` command line: one module per command, nothing else.

Each command module parses its flags, validates them (bad input: one line naming the flag,
exit 2, before any compile), calls the library and writes the run directory. Library modules
(``sern_jax/*.py``, ``sern_jax/grasp/``) never import this package; the command modules are
the only ones that import the script folders (experiments, figures, proofs_check) and hand
their functions to the commands.

* ``main``: the dispatcher (``sern``; the console script is ``sern_jax.commands.main:main``);
* ``regret``: ``sern regret``; ``check``: ``sern check``; ``reproduce``: ``sern reproduce``;
* ``experiment``: ``sern experiment NAME`` (the scripts of ``experiments/``);
* ``bench_bandit``, ``bench_grasp``: ``sern bench bandit|grasp``;
* ``grasp_show``: ``sern grasp show``; ``grasp_learn``: ``sern grasp
  dataset|pretrain|screen|learn``.
"""
