"""A run directory is never mixed between MJX scene structures: the version of the uniform
MJX scenes is part of an MJX run's identity (D0 and learning runs), and of no native run's."""

from sern_jax.grasp.model import dataset
from sern_jax.grasp.world import uniform


def test_the_mjx_program_version_is_in_mjx_fingerprints_only(monkeypatch):
    native, mjx = dataset.DatasetConfig(), dataset.DatasetConfig(backend="mjx")
    before = native.fingerprint(), mjx.fingerprint()
    monkeypatch.setattr(uniform, "MJX_PROGRAM", uniform.MJX_PROGRAM + "-changed")
    assert native.fingerprint() == before[0]
    assert mjx.fingerprint() != before[1]
