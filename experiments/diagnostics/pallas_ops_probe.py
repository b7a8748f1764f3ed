"""Which float32 operation of the fused Pallas kernel differs from XLA's on a GPU?

For the operations the SERN round uses (exp of (r̂ − 1)/α, the add-half division, the tiled
prefix sums, a + b·c), computes each in a Triton kernel (jax.experimental.pallas, as
sern_jax.engine.pallas_softmax does) and in XLA on the same inputs, and records the fraction
of bitwise-equal results; for exp also candidates: libdevice ``__nv_expf`` (jnp.exp),
``ex2.approx.ftz(x·log2 e)`` and NumPy's. Needs an NVIDIA GPU.

Run from the repository root:
    python experiments/diagnostics/pallas_ops_probe.py OUT.json
Records: experiments/results/bench/pallas_ops_probe_h100*.json (see pallas_README.md there).
"""

from __future__ import annotations

import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton

from sern_jax.engine import pallas_softmax

ROWS, K = 1 << 16, 64


def kernel_map(f, *xs):
    def kern(*refs):
        *ins, out = refs
        out[...] = f(*[r[...] for r in ins])

    spec = pl.BlockSpec((16, K), lambda i: (i, 0))
    return pl.pallas_call(kern, out_shape=jax.ShapeDtypeStruct(xs[0].shape, jnp.float32),
                          grid=(xs[0].shape[0] // 16,), in_specs=[spec] * len(xs),
                          out_specs=spec,
                          compiler_params=pltriton.CompilerParams(num_warps=4, num_stages=1))(*xs)


def asm(op, x, *more):
    args = [x, *more]
    cons = "=f," + ",".join("f" for _ in args)
    [y] = pltriton.elementwise_inline_asm(op, args=args, constraints=cons, pack=1,
                                          result_shape_dtypes=[jax.ShapeDtypeStruct(x.shape,
                                                                                    x.dtype)])
    return y


def frac(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.mean(a == b))


def main():
    res = {"jax_version": jax.__version__, "device": jax.devices()[0].device_kind}
    k = jax.random.split(jax.random.key(1), 4)
    n = jnp.floor(jax.random.uniform(k[0], (ROWS, K)) * 10_000.0)
    s = jnp.floor(jax.random.uniform(k[1], (ROWS, K)) * (n + 1.0))
    inv_alpha = 20.0  # 1/α at α = 0.05 (a Python float: kernels take no captured arrays)
    # add-half division
    xla_div = jax.jit(lambda s, n: (s + 0.5) / (n + 1.0))(s, n)
    res["div_rn_equals_xla"] = frac(kernel_map(
        lambda s, n: asm("div.rn.f32 $0, $1, $2;", s + 0.5, n + 1.0), s, n), xla_div)
    res["div_triton_default_equals_xla"] = frac(kernel_map(lambda s, n: (s + 0.5) / (n + 1.0),
                                                           s, n), xla_div)
    # exp of (r - 1)/alpha
    r = jnp.clip(xla_div, 0.0, 1.0)
    x = jax.jit(lambda r: (r - 1.0) * inv_alpha)(r)
    xla_exp = jax.jit(jnp.exp)(x)
    res["arg_equal"] = frac(kernel_map(lambda r: (r - 1.0) * inv_alpha, r), x)
    res["exp_nv_expf_equals_xla"] = frac(kernel_map(jnp.exp, x), xla_exp)
    log2e = 1.4426950408889634
    res["exp_ex2approx_equals_xla"] = frac(kernel_map(
        lambda x: asm("ex2.approx.ftz.f32 $0, $1;", x * log2e), x), xla_exp)
    res["exp_numpy_equals_xla"] = frac(np.exp(np.asarray(x)), xla_exp)
    res["exp_numpy_equals_nv_expf"] = frac(np.exp(np.asarray(x)), kernel_map(jnp.exp, x))
    # composite weights as the kernel computes them
    res["weights_kernel_equals_xla"] = frac(
        kernel_map(lambda s, n: jnp.exp((jnp.clip(asm("div.rn.f32 $0, $1, $2;", s + 0.5,
                                                          n + 1.0), 0.0, 1.0) - 1.0)
                                        * inv_alpha), s, n),
        jax.jit(lambda s, n: jnp.exp((jnp.clip((s + 0.5) / (n + 1.0), 0.0, 1.0) - 1.0)
                                     * inv_alpha))(s, n))
    # tiled prefix sums (two 0/1 dots) against XLA's cumsum
    w = jax.random.uniform(k[2], (ROWS, K)) + 1e-3
    res["tiled16_dots_equal_xla_cumsum"] = frac(
        kernel_map(lambda w: pallas_softmax._tiled_prefix_sums(w, 16), w),
        jax.jit(lambda w: jnp.cumsum(w, axis=1))(w))
    # a + b*c (contraction)
    c = jax.random.uniform(k[3], (ROWS, K))
    xla_fma = jax.jit(lambda a, b, c: a + b * c)(w, s, c)
    res["a_plus_bc_equal"] = frac(kernel_map(lambda a, b, c: a + b * c, w, s, c), xla_fma)
    res["a_plus_bc_xla_is_fma"] = frac(
        np.asarray(xla_fma),
        (np.asarray(w, np.float64) + np.asarray(s, np.float64) * np.asarray(c, np.float64)
         ).astype(np.float32))
    print(json.dumps(res, indent=1), flush=True)
    with open(sys.argv[1], "w") as fh:
        json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
