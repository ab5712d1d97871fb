"""Fused multiply-add in numba kernels, and the 3×3 product that rounds as numpy's stacked matmul does here.

``fma(x, y, z)`` is ``x·y + z`` rounded once (LLVM's ``llvm.fma.f64``: one instruction on CPUs with FMA, a correctly
rounded software routine elsewhere). numpy's ``A @ B`` on stacks of 3×3 float64 matrices forms each entry as
``fma(a2, b2, fma(a1, b1, a0·b0))`` on this project's machines (OpenBLAS's FMA kernels; checked entry by entry on
10⁵ random products and by ``tests/test_speed_kernels.py``), so :func:`matmul33` inside a kernel gives numpy's
values bit for bit without a BLAS call per matrix.
"""

from __future__ import annotations

import numba as nb
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic


@intrinsic
def fma(typingctx, x, y, z):
    """``x * y + z`` with one rounding (float64; numba kernels only)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma.f64", fnty=ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


@nb.njit(cache=True, inline="always")
def matmul33(A, B, out):
    """``out = A @ B`` for one 3×3 pair (2-D arrays or views), each entry ``fma(a2, b2, fma(a1, b1, a0·b0))``;
    ``out`` must not alias ``A`` or ``B``."""
    for a in range(3):
        for c in range(3):
            out[a, c] = fma(A[a, 2], B[2, c], fma(A[a, 1], B[1, c], A[a, 0] * B[0, c]))


@nb.njit(cache=True, inline="always")
def rigid_point(R, t, c0, c1, c2):
    """``R @ (c0, c1, c2) + t`` (``R`` (3, 3), ``t`` (3,)), each coordinate ``fma(c2, r2, fma(c1, r1, c0·r0)) + t``:
    one row of ``corners @ R.T + t`` as numpy's BLAS product of a corner stack rounds it here."""
    x = fma(c2, R[0, 2], fma(c1, R[0, 1], c0 * R[0, 0])) + t[0]
    y = fma(c2, R[1, 2], fma(c1, R[1, 1], c0 * R[1, 0])) + t[1]
    z = fma(c2, R[2, 2], fma(c1, R[2, 1], c0 * R[2, 0])) + t[2]
    return x, y, z
