"""MJX's Newton step with the elliptic cones' Hessian assembled from per-contact blocks.

Every grasp scene uses MuJoCo's Newton solver with elliptic friction cones. In each Newton
iteration MJX (``mujoco.mjx._src.solver._update_gradient``) builds the constraint Hessian
as ``J' C J``, where ``C`` is a dense ``nefc x nefc`` matrix: ``diag(D * active)`` plus one
``condim x condim`` cone block per contact, each added by its own ``.at[...].add`` in a
Python loop. Its cost grows with ``nefc**2`` per contact, and on a GPU each block is a
separate update of a ``[batch, nefc, nefc]`` array. A uniform scene
(:mod:`sern_jax.grasp.world.uniform`) has 16 contact pairs (4 parts x table, palm and two
pads), 64 contacts and 226 constraint rows, so on a CPU that loop is most of a trial step
(docs/PERFORMANCE.md, "What bounds an MJX trial").

:func:`cone_hessian` computes the same matrix as a sum that never forms ``C``::

    H = J' diag(D * active) J  +  sum_c J_c' H_c J_c

where ``J_c`` holds the ``condim`` rows of contact ``c`` and ``H_c`` its cone block. The
two are equal in exact arithmetic; in floating point the summation order differs, so a
trajectory may differ from MJX's in the last bits (and, through contacts that switch,
beyond: tests/grasp/test_mjx_solver.py checks the Hessians and paired trials).

Scope: the replacement is active only while a function wrapped by :func:`block_hessian` is
being traced (the trial programs of :mod:`sern_jax.grasp.world.sim`). Elsewhere in the
process, ``mujoco.mjx`` runs its own code: :func:`install` puts a dispatcher in place of
``_update_gradient`` that calls MJX's original unless the tracing thread asked for blocks.
"""

from __future__ import annotations

import contextlib
import functools
import threading

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["HESSIANS", "cone_hessian", "block_hessian", "install"]

HESSIANS = ("blocks", "mjx")  # "mjx": MJX's own dense assembly, the reference

_state = threading.local()
_install_lock = threading.Lock()
_original = None


def _solver():
    from sern_jax.grasp.world._mjx import mjx  # noqa: F401  (quiet import of mujoco.mjx)
    from mujoco.mjx._src import solver

    return solver


def cone_hessian(efc_J, efc_D, active, cone_h, efc_address, dim):
    """The constraint part of the Newton Hessian, ``J' (diag(D active) + blocks) J``.

    Args:
      efc_J: [nefc, nv] constraint Jacobian.
      efc_D: [nefc] constraint mass.
      active: [nefc] active mask (bool or 0/1).
      cone_h: [ncone, 6, 6] cone blocks (MJX's ``Context.h``; entries past a contact's
        ``condim`` are ignored).
      efc_address: [ncone] static first constraint row of each cone (NumPy).
      dim: [ncone] static ``condim`` of each cone (NumPy).

    Returns:
      [nv, nv].
    """
    h = (efc_J.T * (efc_D * active)[None, :]) @ efc_J
    efc_address, dim = np.asarray(efc_address), np.asarray(dim)
    if efc_address.size == 0:
        return h
    k = np.arange(6)
    mask = k[None] < dim[:, None]  # [ncone, 6], static
    rows = np.where(mask, efc_address[:, None] + k[None], 0)
    jc = efc_J[rows] * mask[..., None]  # [ncone, 6, nv]
    hc = cone_h * (mask[:, :, None] & mask[:, None, :])
    return h + jnp.einsum("cki,ckl,clj->ij", jc, hc, jc)


def _update_gradient_blocks(m, d, ctx):
    """MJX's ``_update_gradient`` for the Newton solver with elliptic cones, blocks form."""
    from mujoco.mjx._src import support

    grad = ctx.Ma - d.qfrc_smooth - ctx.qfrc_constraint
    impl = d._impl
    sel = np.asarray(impl.contact.dim) > 1
    h = cone_hessian(impl.efc_J, impl.efc_D, ctx.active, ctx.h,
                     np.asarray(impl.contact.efc_address)[sel],
                     np.asarray(impl.contact.dim)[sel])
    h = support.full_m(m, d) + h
    h_sym = (h + h.T) * 0.5  # as MJX: symmetric before the Cholesky factorisation
    mgrad = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(h_sym), grad)
    return ctx.replace(grad=grad, Mgrad=mgrad)


def _dispatch(m, d, ctx):
    solver = _solver()
    if (getattr(_state, "blocks", 0) and m.opt.solver == solver.SolverType.NEWTON
            and m.opt.cone == solver.ConeType.ELLIPTIC):
        return _update_gradient_blocks(m, d, ctx)
    return _original(m, d, ctx)


def install() -> None:
    """Puts the dispatcher in place of MJX's ``_update_gradient`` (once per process). It
    calls MJX's original function except while :func:`block_hessian` code is traced."""
    global _original
    with _install_lock:
        solver = _solver()
        if not hasattr(solver, "_update_gradient"):
            raise RuntimeError("mujoco.mjx has no solver._update_gradient: this mujoco-mjx "
                               "version is not supported by sern_jax's block Hessian")
        if solver._update_gradient is _dispatch:
            return
        _original = solver._update_gradient
        solver._update_gradient = _dispatch


@contextlib.contextmanager
def _blocks_on():
    _state.blocks = getattr(_state, "blocks", 0) + 1
    try:
        yield
    finally:
        _state.blocks -= 1


def block_hessian(fn, hessian: str = "blocks"):
    """``fn`` traced with the block Hessian (``hessian="blocks"``) or with MJX's own
    (``"mjx"``, ``fn`` unchanged). Wrap the function that ``jit`` traces."""
    if hessian not in HESSIANS:
        raise ValueError(f"hessian must be one of {HESSIANS}, got {hessian!r}")
    if hessian == "mjx":
        return fn
    install()

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with _blocks_on():
            return fn(*args, **kwargs)

    return wrapped
