"""Online grasp learning (Algorithm 1): the batched runner, the ask/tell robot loop
(``asktell``), Ray units (``learn_units``) and the run's resource estimate (``budget``)."""
