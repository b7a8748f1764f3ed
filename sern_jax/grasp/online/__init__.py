"""Online grasp learning (Algorithm 1): the run's settings (``config``), random streams
(``keys``), one round as pure functions (``step``), the host loop (``driver``: ``run``),
results and checkpoint (``checkpoint``), the ask/tell robot loop (``asktell``), Ray units
(``learn_units``), the run's resource estimate (``budget``) and the benchmarks shipped as
package data (``benchmark``: objects, world, protocol, seeds and tuned learners of one
comparison)."""
