"""The seed engines: one seed (``simulate``), the fast exact runners (``fast_softmax``,
``fast_thompson``, ``pallas_softmax``), neural learners on synthetic problems (``networks``,
``neural``), and the one driver over thousands of seeds (``drive.run_seeds``)."""
