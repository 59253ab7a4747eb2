"""The numba decorators of the model kernels: one set of compile options for the whole model.

``fastmath`` stays off, so that results are bit for bit identical between the single env, every
sub-env of the vector env and every SIMD lane (no FMA contraction, no reassociation). The error model
is numpy's (x/0 gives inf/nan instead of raising), which the vectoriser needs; no division in the
model has a zero denominator for valid parameters. ``cache=True`` keeps the compiled code on disk, in
the directory of this source version (:mod:`softpvtol_gym._cache`).
"""

from __future__ import annotations

from numba import njit

#: a compiled function (one copy, called)
jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
#: small pure functions: inlined into every caller (needed for the SIMD lane loops)
inline = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")
#: the batched wrappers (:mod:`.batched`): python error model, GIL released
batch_jit = njit(cache=True, nogil=True)
