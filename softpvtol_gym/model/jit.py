"""The numba decorators of the model kernels: one set of compile options for the whole model.

``fastmath`` stays off, so that results are bit for bit identical between the single env, every
sub-env of the vector env and every SIMD lane (no FMA contraction, no reassociation). The error model
is numpy's (x/0 gives inf/nan instead of raising), which the vectoriser needs; no division in the
model has a zero denominator for valid parameters. ``cache=True`` keeps the compiled code on disk, in
the directory of this source version (:mod:`softpvtol_gym._cache`).

Inlining. A loop over a block of lanes becomes SIMD code only if its whole body is inlined, so the
small functions marked :data:`inline` are inlined by numba into the SIMD kernels (:data:`SIMD_KERNELS`)
and into nothing else: every other caller calls one compiled copy (LLVM still inlines where it pays).
Numba types every inlined copy again, which was most of the cold compile (an RK4 step inlines four
stages of the model); IEEE arithmetic without fastmath is the same inlined or called, so the results
do not depend on the choice (the tests compare the SIMD and the scalar paths bit for bit).
"""

from __future__ import annotations

from numba import njit

#: the kernels with a loop over a lane block that LLVM vectorises: the small functions are inlined into them
SIMD_KERNELS = frozenset({
    "rk4_lanes",  # model.lanes: the RK4 step of a full lane block
    "diag_lanes",  # envs.diagnostics: energy and storage of a full lane block
    "controller_model_lanes",  # control._block_kernels: D, C, g of a controller block
    "lever_poly_lanes",  # control._allocation_kernels: the allocation's polynomials of a block
})


def inline_into_simd_kernels(expr, caller_ir, callee_ir) -> bool:
    """numba's inlining decision for :data:`inline` functions (a cost model of numba's untyped inlining:
    the call expression, the caller's and the callee's ``FunctionIR``): inline into :data:`SIMD_KERNELS` only."""
    return caller_ir.func_id.func_name in SIMD_KERNELS


#: a compiled function (one copy, called)
jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
#: the model's pure functions: inlined into the SIMD kernels, a compiled call everywhere else
inline = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline=inline_into_simd_kernels)
#: accessors (a few loads or stores: lane and row helpers): inlined into every caller (cheaper than a call
#: and a compile of their own)
accessor = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
#: the batched wrappers (:mod:`.batched`): python error model, GIL released
batch_jit = njit(cache=True, nogil=True)
