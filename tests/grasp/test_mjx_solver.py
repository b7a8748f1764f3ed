"""The block assembly of the Newton Hessian (sern_jax.grasp.world.mjx_solver) equals MJX's
dense one, and it replaces MJX's only inside the functions wrapped for it."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from sern_jax.grasp.world import mjx_solver
from sern_jax.grasp.world._mjx import mjx


def _dense(efc_J, efc_D, active, cone_h, efc_address, dim):
    """MJX's assembly: J' C J with C = diag(D active) plus each cone block added in place."""
    c = np.diag(efc_D * active)
    for i, (condim, addr) in enumerate(zip(dim, efc_address)):
        c[addr:addr + condim, addr:addr + condim] += cone_h[i, :condim, :condim]
    return efc_J.T @ c @ efc_J


def _problem(seed):
    rng = np.random.default_rng(seed)
    kinds = rng.choice([1, 3, 4, 6], size=rng.integers(1, 12))  # 1: a frictionless contact
    nv = int(rng.integers(2, 14))
    nefc = int(kinds.sum()) + int(rng.integers(0, 5))  # other rows (limits) at the end
    addr = np.concatenate([[0], np.cumsum(kinds)[:-1]])
    cones = kinds > 1
    h = rng.normal(size=(int(cones.sum()), 6, 6))
    h = h + h.transpose(0, 2, 1)
    return (rng.normal(size=(nefc, nv)), rng.uniform(0.1, 2, nefc),
            rng.random(nefc) < 0.6, h, addr[cones], kinds[cones])


@pytest.mark.parametrize("seed", range(6))
def test_block_hessian_equals_the_dense_assembly(seed):
    J, D, active, h, addr, dim = _problem(seed)
    got = np.asarray(mjx_solver.cone_hessian(jnp.asarray(J), jnp.asarray(D),
                                             jnp.asarray(active), jnp.asarray(h), addr, dim))
    want = _dense(J, D, active, h, addr, dim)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
    if len(addr):  # control: without the cone blocks the matrices differ
        without = _dense(J, D, active, np.zeros_like(h), addr, dim)
        assert not np.allclose(without, want)


def test_entries_past_a_contacts_condim_are_ignored():
    J, D, active, h, addr, dim = _problem(3)
    noisy = h.copy()
    for i, condim in enumerate(dim):
        noisy[i, condim:, :] = 99.0
        noisy[i, :, condim:] = 99.0
    a = mjx_solver.cone_hessian(J, D, active, h, addr, dim)
    b = mjx_solver.cone_hessian(J, D, active, noisy, addr, dim)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)


_SLIDING_BOX = """
<mujoco>
  <option solver="Newton" cone="elliptic" iterations="20" ls_iterations="20"/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body pos="0 0 0.0495"><freejoint/>
      <geom type="box" size="0.05 0.05 0.05" condim="4" friction="0.4 0.02"/></body>
  </worldbody>
</mujoco>
"""


def _sliding_box():
    model = mujoco.MjModel.from_xml_string(_SLIDING_BOX)
    data = mujoco.MjData(model)
    data.qvel[0] = 0.5  # the box slides: its cones are in the middle zone
    mujoco.mj_forward(model, data)
    return mjx.put_model(model), mjx.put_data(model, data)


def test_the_newton_direction_equals_mjxs():
    """The whole replacement (Hessian, Cholesky, direction) against MJX's own function on
    one solver context, away from the optimum (qacc shifted) with cones in the middle zone."""
    from mujoco.mjx._src import solver

    mx, d = _sliding_box()
    d = d.replace(qacc=d.qacc + 1.0)
    mjx_solver.install()

    def directions(m, d):
        with jax.numpy_rank_promotion("allow"):  # MJX's own code promotes ranks
            ctx = solver.Context.create(m, d, grad=False)
            blocks = mjx_solver._update_gradient_blocks(m, d, ctx).Mgrad
            without = mjx_solver._update_gradient_blocks(m, d, ctx.replace(h=0 * ctx.h)).Mgrad
            return blocks, mjx_solver._original(m, d, ctx).Mgrad, without, ctx.h

    blocks, reference, without, h = (np.asarray(x) for x in jax.jit(directions)(mx, d))
    assert np.abs(h).max() > 0.1  # the cone blocks are not zero
    np.testing.assert_allclose(blocks, reference, rtol=1e-4, atol=1e-6 * np.abs(reference).max())
    assert not np.allclose(without, reference, rtol=1e-3)  # control: the blocks matter


def test_blocks_only_inside_the_wrapped_function(monkeypatch):
    mx, d = _sliding_box()
    calls = []
    blocks = mjx_solver._update_gradient_blocks
    monkeypatch.setattr(mjx_solver, "_update_gradient_blocks",
                        lambda *a: calls.append(1) or blocks(*a))

    def forward(m, d):
        with jax.numpy_rank_promotion("allow"):  # MJX's own code promotes ranks
            return mjx.forward(m, d).qacc

    jax.make_jaxpr(forward)(mx, d)  # traced outside: MJX's own assembly
    assert not calls
    jax.make_jaxpr(mjx_solver.block_hessian(forward))(mx, d)  # inside: the block assembly
    assert calls
    n = len(calls)
    jax.make_jaxpr(forward)(mx, d)  # and outside again afterwards
    assert len(calls) == n
    assert mjx_solver.block_hessian(forward, "mjx") is forward


def test_unknown_hessian_is_refused():
    with pytest.raises(ValueError, match="hessian"):
        mjx_solver.block_hessian(lambda: None, "dense")
