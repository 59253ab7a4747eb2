"""Compiled condensing of the MPC's QP (single-threaded numba loops).

NumPy's matrix products would call a multi-threaded BLAS, whose threads spin against each other on a
loaded 2-core machine (a 250 x 100 Gram matrix took 16 ms with OpenBLAS's threads, 0.2 ms with one);
these loops stay on the calling thread and use the block lower-triangular structure of the
sensitivities.
"""

from __future__ import annotations

from numba import njit

NX, NU = 10, 4


@njit(cache=True, nogil=True)
def condense(A, B, v_scale, W, err, G, H, g):
    """Sensitivities and the Gauss-Newton QP of the state cost, in place.

    A (10, 10 N) = [A_0 .. A_{N-1}], B (10, 4 N) = [B_0 .. B_{N-1}] the interval Jacobians dx_{k+1}/dx_k
    and dx_{k+1}/du_k; v_scale (4): u = u_hover + v_scale v. Fills G (10 N, 4 N), G[block k, block j] =
    dx_{k+1}/dv_j (zero for j > k), H (4 N, 4 N) = G^T diag(W) G and g (4 N) = G^T (W err) for the
    state weights W (10 N) and the state errors err (10 N) of nodes 1 .. N.
    """
    n = A.shape[1] // NX
    nv = NU * n
    for k in range(n):
        r0 = NX * k
        for i in range(NX):
            for c in range(NU * k):
                s = 0.0
                for m in range(NX):
                    s += A[i, r0 + m] * G[r0 - NX + m, c]
                G[r0 + i, c] = s
            for c in range(NU):
                G[r0 + i, NU * k + c] = B[i, NU * k + c] * v_scale[c]
            for c in range(NU * (k + 1), nv):
                G[r0 + i, c] = 0.0
    for a in range(nv):
        s = 0.0
        for r in range(NX * (a // NU), NX * n):
            s += G[r, a] * W[r] * err[r]
        g[a] = s
        for b in range(a + 1):
            s = 0.0
            for r in range(NX * (a // NU), NX * n):  # a >= b: rows of node blocks >= a's interval
                s += G[r, a] * W[r] * G[r, b]
            H[a, b] = s
            H[b, a] = s
