"""The MPC's quadratic programs in the two forms its solvers take (see :mod:`.ocp` for the problem): condensed
(the inputs as variables, for the dense solvers) and sparse with the OCP's stage structure (states and inputs as
variables: banded for PIQP, HPIPM's stage form for HPIPM), all with the curvature slacks; :class:`_Buffered`,
a CasADi Function called on NumPy arrays in place; and :class:`_PiqpQP`, PIQP's sparse solver behind the same
arrays."""

from __future__ import annotations

import numpy as np

from ._casadi import import_casadi
from ._kernels import condense

NX, NU = 10, 4
#: slacks per node (one per arm: q_l, q_r)
NS = 2
#: price of a curvature bound violation [cost units per rad]: the QP's L1 penalty on its slacks and the
#: line search's merit (far above the curvature limit's multipliers in the QPs met: an exact penalty)
VIOLATION_PENALTY = 1e4
#: the QP's quadratic weight on the curvature slacks (keeps the QP strictly convex in them)
SLACK_WEIGHT = 1.0
#: the bound of the sparse QP's unbounded variables (state steps) for HPIPM (PIQP takes them unbounded)
FREE_BOUND = 1e4


def _differences(V: np.ndarray, v_prev: np.ndarray) -> np.ndarray:
    """D V - (v_prev, 0, ..): the changes v_k - v_{k-1} of the stacked inputs V (4 N), v_{-1} = v_prev."""
    dv = V.copy()
    dv[NU:] -= V[:-NU]
    dv[:NU] -= v_prev
    return dv


class _CondensedQP:
    """The Gauss-Newton QP in the input steps alone (states eliminated by the compiled condensing): a
    dense 4N x 4N Hessian, and the N x 2 curvature slacks s >= 0 as variables after the input steps, with
    the 4N rows G dv + s >= -q_max - q, G dv - s <= q_max - q. For the dense solvers."""

    def __init__(self, n: int, state_weights: np.ndarray, weight_input: float, weight_input_rate: float):
        ca = import_casadi()
        nv = NU * n
        ns = NS * n
        self.n, self.nv, self.W, self.wu, self.wd = n, nv, state_weights, weight_input, weight_input_rate
        self.sparsity = {"h": ca.Sparsity.dense(nv + ns, nv + ns), "a": ca.Sparsity.dense(2 * ns, nv + ns)}
        self.solver_options = {}
        # input cost: R on v_k, R_d on v_k - v_{k-1}: H_u = R I + R_d D^T D (D the difference operator)
        D = np.eye(nv) - np.eye(nv, k=-NU)
        self._input_hessian = weight_input * np.eye(nv) + weight_input_rate * D.T @ D
        self._G = np.zeros((NX * n, nv))
        self._Hu = np.zeros((nv, nv))
        self._H = np.zeros((nv + ns, nv + ns))
        self._H[nv:, nv:] = SLACK_WEIGHT * np.eye(ns)
        self._A = np.zeros((2 * ns, nv + ns))
        self._A[:ns, nv:] = np.eye(ns)
        self._A[ns:, nv:] = -np.eye(ns)
        self._g = np.zeros(nv)
        self._arm_rows = np.concatenate([np.arange(NX * k + 3, NX * k + 5) for k in range(n)])

    def prepare(self, qp: _Buffered) -> None:
        """The slacks' constant entries: their linear cost, their bounds, the rows' open sides."""
        nv, ns = self.nv, NS * self.n
        arg = qp.named_args
        arg["g"][nv:] = VIOLATION_PENALTY
        arg["lbx"][nv:] = 0.0
        arg["ubx"][nv:] = FREE_BOUND
        arg["uba"][:ns] = FREE_BOUND
        arg["lba"][ns:] = -FREE_BOUND

    def fill(self, qp: _Buffered, A, B, u_scale, X, x_ref, V, v_prev, lo, hi, qmax) -> None:
        """The QP's arguments into the solver instance's arrays."""
        nv, ns = self.nv, NS * self.n
        G, Hu, g_state = self._G, self._Hu, self._g
        condense(A, B, u_scale, self.W, (X - x_ref).reshape(-1), G, Hu, g_state)
        H = self._H
        H[:nv, :nv] = Hu + self._input_hessian
        dv = _differences(V, v_prev)
        dtd = dv.copy()  # D^T dv
        dtd[:-NU] -= dv[NU:]
        qa = X[:, 3:5].reshape(-1)
        self._A[:ns, :nv] = G[self._arm_rows]
        self._A[ns:, :nv] = G[self._arm_rows]
        arg = qp.named_args
        arg["h"][:] = H.reshape(-1)  # symmetric: its column-major order is its row-major one
        arg["g"][:nv] = g_state + self.wu * V + self.wd * dtd
        arg["a"][:] = self._A.T.reshape(-1)  # column-major
        arg["lba"][:ns] = -qmax - qa
        arg["uba"][ns:] = qmax - qa
        arg["lbx"][:nv] = lo - V
        arg["ubx"][:nv] = hi - V

    def input_step(self, qp: _Buffered) -> np.ndarray:
        return qp.named_res["x"][:self.nv].copy()

    def slacks(self, qp: _Buffered) -> np.ndarray:
        """The curvature slacks of the last solve, (N, 2) [rad]."""
        return qp.named_res["x"][self.nv:].reshape(self.n, NS).copy()


class _StagedQP:
    """What the QP's two forms with its stage structure share (:class:`_SparseQP`, :class:`_BandedQP`): the
    constant entries of A and H from their coordinates, the values that change each solve (the interval
    Jacobians, the gradient's state part, the input bounds and the curvature rows), and the solution's parts.
    A subclass sets the columns ``ucols`` (4 N: dv_0 .. dv_{N-1}), ``xcols`` ((N, >= 10): node k's state step
    in its first 10), ``scols`` ((N, 2): node k's slacks), the rows ``dynamics_rows``, ``lower_rows`` and
    ``upper_rows`` ((N, 2) each), then calls :meth:`_structure`."""

    def _structure(self, ca, a_rows: list, a_cols: list, a_consts: list, h_diag: np.ndarray, h_off: tuple) -> None:
        """The sparsities and constant values of A and H. A's entries: the interval Jacobians A_k (k >= 1) and
        B_k S first (their (row, col) arrays in ``a_rows`` / ``a_cols``, as many as ``_n_a + _n_b``), then
        the constant entries with their values ``a_consts``; the curvature rows' entries are added here. H:
        the diagonal ``h_diag`` and -wd at the symmetric pairs ``h_off`` = (rows, cols)."""
        for k in range(self.n):  # node k+1's curvature rows: dq + s (lower bound), dq - s (upper bound)
            for j in range(NS):
                for row, sign in ((self.lower_rows[k, j], 1.0), (self.upper_rows[k, j], -1.0)):
                    a_rows.append(np.array([row, row]))
                    a_cols.append(np.array([self.xcols[k, 3 + j], self.scols[k, j]]))
                    a_consts.append(np.array([1.0, sign]))
        rows = np.concatenate([r.ravel() for r in a_rows])
        cols = np.concatenate([c.ravel() for c in a_cols])
        self._n_a, self._n_b = NX * NX * (self.n - 1), NX * NU * self.n
        a_sp, self._a_order = _sparsity_and_order(ca, rows, cols, self.nrow, self.nvar)
        self._a_values = np.zeros(rows.size)
        self._a_values[self._n_a + self._n_b:] = np.concatenate(a_consts)
        off_r, off_c = h_off
        hr = np.concatenate([np.arange(self.nvar), off_r, off_c])
        hc = np.concatenate([np.arange(self.nvar), off_c, off_r])
        hv = np.concatenate([h_diag, np.full(off_r.size, -self.wd), np.full(off_c.size, -self.wd)])
        keep = hv != 0.0
        h_sp, order = _sparsity_and_order(ca, hr[keep], hc[keep], self.nvar, self.nvar)
        self._h_values = hv[keep][order]
        self.sparsity = {"h": h_sp, "a": a_sp}

    def prepare(self, qp) -> None:
        """The constant Hessian, dynamics residuals, slack costs and bounds, and open sides into the
        instance's arrays. The state steps, unbounded, get wide finite bounds: HPIPM bounds every variable,
        and at its default replacement of an infinite bound (1e8) its interior point iterations stall (100
        iterations without convergence); its ``inf`` option did not keep its calls independent (a call's
        result depended on the call before it). PIQP takes them as infinite (:class:`_PiqpQP`)."""
        arg = qp.named_args
        arg["h"][:] = self._h_values
        arg["lba"][self.dynamics_rows] = 0.0
        arg["uba"][self.dynamics_rows] = 0.0
        arg["uba"][self.lower_rows] = FREE_BOUND
        arg["lba"][self.upper_rows] = -FREE_BOUND
        arg["lbx"][:] = -FREE_BOUND
        arg["ubx"][:] = FREE_BOUND
        arg["lbx"][self.scols] = 0.0
        arg["g"][self.scols] = VIOLATION_PENALTY

    def _fill_common(self, qp, A, B, u_scale, X, x_ref, V, lo, hi, qmax) -> None:
        """The interval Jacobians, the state part of the gradient, the input bounds and the curvature rows'
        bounds into the instance's arrays."""
        n = self.n
        vals = self._a_values
        vals[:self._n_a] = A[:, NX:].reshape(NX, n - 1, NX).transpose(1, 0, 2).reshape(-1)
        vals[self._n_a:self._n_a + self._n_b] = (B.reshape(NX, n, NU) * u_scale).transpose(1, 0, 2).reshape(-1)
        arg = qp.named_args
        np.take(vals, self._a_order, out=arg["a"])
        arg["g"][self.xcols[:, :NX]] = self.W * (X - x_ref)
        arg["lbx"][self.ucols] = lo - V
        arg["ubx"][self.ucols] = hi - V
        arg["lba"][self.lower_rows] = -qmax - X[:, 3:5]
        arg["uba"][self.upper_rows] = qmax - X[:, 3:5]

    def input_step(self, qp) -> np.ndarray:
        return qp.named_res["x"][self.ucols]

    def slacks(self, qp) -> np.ndarray:
        """The curvature slacks of the last solve, (N, 2) [rad]."""
        return qp.named_res["x"][self.scols].copy()


class _SparseQP(_StagedQP):
    """The same Gauss-Newton QP in HPIPM's stage form (HPIPM is a Riccati-based interior point method: work
    linear in N, against cubic for a dense QP in the 4N inputs).

    Variables (the state steps of the rollout and the input steps, in stage order): u_0, then for
    k = 1 .. N-1 (x_k, u_k), then x_N, where u_k = (dv_k (4), w_k (2)) and x_k = (dx_k (10), p_k (4),
    s_k (2)): p_k = dv_{k-1} carries the previous stage's input step, so that the input-rate cost
    |v_k + dv_k - v_{k-1} - p_k|^2 is a cost of stage k alone (HPIPM's stage costs cannot couple two
    stages), and s_k = w_{k-1} >= 0 is node k's curvature slack, chosen one stage ahead as an input (stage
    N has no inputs) and carried into the stage whose curvatures it relaxes. x_0 = 0 is not a variable (the
    measured state: no step). Constraints: the linearised dynamics, dx_{k+1} = A_k dx_k + B_k S dv_k,
    p_{k+1} = dv_k, s_{k+1} = w_k (S = diag(u_scale)), as the equality rows HPIPM eliminates by its
    Riccati recursion; the actuator limits as bounds on dv_k; and at each node k = 1 .. N four rows of
    stage k, dq_k + s_k >= -q_max - q_k and dq_k - s_k <= q_max - q_k (q = (q_l, q_r) of the rollout).
    The rollout is the model's (single shooting): the dynamics rows have no residual. CasADi's HPIPM
    interface takes the rows in the order (dynamics of interval 0, rows of stage 0, dynamics of interval 1,
    rows of stage 1, ..., rows of stage N).
    """

    def __init__(self, n: int, state_weights: np.ndarray, weight_input: float, weight_input_rate: float):
        ca = import_casadi()
        nxa = NX + NU + NS  # augmented state (dx, p, s)
        nua = NU + NS  # augmented input (dv, w)
        ng = 2 * NS  # curvature rows per stage k >= 1
        self.n, self.wu, self.wd = n, weight_input, weight_input_rate
        self.W = state_weights.reshape(n, NX)
        # column offsets: u_k's first column, x_k's first column (k >= 1)
        ucol = np.array([0] + [nua + (nxa + nua) * (k - 1) + nxa for k in range(1, n)])
        xcol = np.array([-1] + [nua + (nxa + nua) * (k - 1) for k in range(1, n + 1)])
        self.nvar = int(xcol[n] + nxa)
        self.ucols = (ucol[:, None] + np.arange(NU)).reshape(-1)
        self.wcols = (ucol[:, None] + NU + np.arange(NS)).reshape(-1)
        self.xcols = xcol[1:, None] + np.arange(nxa)  # (N, 16): x_k, k = 1 .. N
        self.scols = self.xcols[:, NX + NU:]  # (N, 2): s_k
        self.solver_options = {"N": n, "nx": [0] + [nxa] * n, "nu": [nua] * n + [0], "ng": [0] + [ng] * n}
        # row offsets: dynamics of interval k, then the rows of stage k (none at stage 0)
        dyn_row = np.array([k * nxa + ng * max(k - 1, 0) for k in range(n)])
        stage_row = np.array([-1] + [dyn_row[k] + nxa for k in range(1, n)] + [n * nxa + ng * (n - 1)])
        self.nrow = n * nxa + ng * n
        #: rows q + s >= lo and q - s <= hi of stages 1 .. N, (N, 2) each
        self.lower_rows = stage_row[1:, None] + np.arange(NS)
        self.upper_rows = stage_row[1:, None] + NS + np.arange(NS)
        self.dynamics_rows = (dyn_row[:, None] + np.arange(nxa)).reshape(-1)

        rows, cols, consts = [], [], []
        i10, j10 = np.meshgrid(np.arange(NX), np.arange(NX), indexing="ij")
        for k in range(1, n):  # A_k (interval 0 starts at x_0, not a variable)
            rows.append(dyn_row[k] + i10)
            cols.append(xcol[k] + j10)
        i4, j4 = np.meshgrid(np.arange(NX), np.arange(NU), indexing="ij")
        for k in range(n):  # B_k S
            rows.append(dyn_row[k] + i4)
            cols.append(ucol[k] + j4)
        for k in range(n):  # p_{k+1} = dv_k, s_{k+1} = w_k
            rows.append(dyn_row[k] + NX + np.arange(NU + NS))
            cols.append(ucol[k] + np.arange(NU + NS))
            consts.append(np.ones(NU + NS))
        for k in range(n):  # - x_{k+1}
            rows.append(dyn_row[k] + np.arange(nxa))
            cols.append(xcol[k + 1] + np.arange(nxa))
            consts.append(-np.ones(nxa))
        # Hessian (constant): W on dx_k, wu + wd on dv_k, wd on p_k and -wd between dv_k and p_k (k >= 1),
        # SLACK_WEIGHT on s_k
        diag = np.zeros(self.nvar)
        diag[self.ucols] = weight_input + weight_input_rate
        diag[self.xcols[:, :NX]] = self.W
        diag[self.xcols[:-1, NX:NX + NU]] = weight_input_rate
        diag[self.scols] = SLACK_WEIGHT
        self._structure(ca, rows, cols, consts, diag, (self.xcols[:-1, NX:NX + NU].reshape(-1), self.ucols[NU:]))

    def prepare(self, qp: _Buffered) -> None:
        super().prepare(qp)
        qp.named_args["lbx"][self.wcols] = 0.0  # the slacks chosen one stage ahead

    def fill(self, qp: _Buffered, A, B, u_scale, X, x_ref, V, v_prev, lo, hi, qmax) -> None:
        """The QP's arguments into the solver instance's arrays."""
        self._fill_common(qp, A, B, u_scale, X, x_ref, V, lo, hi, qmax)
        Vk = V.reshape(self.n, NU)
        change = Vk.copy()  # c_k = v_k - v_{k-1}
        change[1:] -= Vk[:-1]
        change[0] -= v_prev
        g = qp.named_args["g"]
        g[self.ucols] = (self.wu * Vk + self.wd * change).reshape(-1)
        g[self.xcols[:-1, NX:NX + NU]] = -self.wd * change[1:]


class _BandedQP(_StagedQP):
    """The same Gauss-Newton QP in its plain sparse form, for PIQP: no variable but the QP's own, the
    input-rate cost as Hessian entries between consecutive stages (a block-banded KKT system, which PIQP's
    ``sparse_multistage`` KKT solver factors stage by stage). 16 variables per stage instead of the 22 of
    :class:`_SparseQP`, whose stage costs cannot couple two stages.

    Variables, in stage order: dv_0, then for k = 1 .. N-1 (dx_k (10), s_k (2), dv_k (4)), then (dx_N, s_N),
    where dx_k is node k's state step, s_k >= 0 its curvature slacks and dv_k the step of the normalised input
    of interval k. Rows: the linearised dynamics of each interval, dx_{k+1} = A_k dx_k + B_k S dv_k (dx_0 = 0,
    S = diag(u_scale)), then per node k = 1 .. N the four curvature rows dq_k + s_k >= -q_max - q_k and
    dq_k - s_k <= q_max - q_k. Cost: |X + dX - x_ref|^2_W + wu |V + dV|^2 + wd |D (V + dV) - (v_prev, 0, ..)|^2
    (D the difference operator) + the slacks' VIOLATION_PENALTY s + SLACK_WEIGHT s^2 / 2, as in the module
    docstring of :mod:`.ocp`."""

    def __init__(self, n: int, state_weights: np.ndarray, weight_input: float, weight_input_rate: float):
        ca = import_casadi()
        self.n, self.wu, self.wd = n, weight_input, weight_input_rate
        self.W = state_weights.reshape(n, NX)
        stage = NX + NS + NU
        # first column of node k's (dx_k, s_k, dv_k) block, k = 1 .. N; dv_0 takes columns 0 .. NU-1
        block = NU + stage * np.arange(n)
        self.nvar = int(block[-1] + NX + NS)
        self.xcols = block[:, None] + np.arange(NX)  # (N, 10): dx_k, k = 1 .. N
        self.scols = block[:, None] + NX + np.arange(NS)  # (N, 2): s_k
        self.ucols = np.concatenate([np.arange(NU), (block[:-1, None] + NX + NS + np.arange(NU)).reshape(-1)])
        ucols = self.ucols.reshape(n, NU)
        self.dynamics_rows = np.arange(NX * n)
        self.lower_rows = NX * n + NS * 2 * np.arange(n)[:, None] + np.arange(NS)  # (N, 2)
        self.upper_rows = self.lower_rows + NS
        self.nrow = NX * n + 2 * NS * n

        rows, cols, consts = [], [], []
        i10, j10 = np.meshgrid(np.arange(NX), np.arange(NX), indexing="ij")
        for k in range(1, n):  # A_k on dx_k (interval 0 starts at dx_0 = 0, not a variable)
            rows.append(NX * k + i10)
            cols.append(self.xcols[k - 1][j10])
        i4, j4 = np.meshgrid(np.arange(NX), np.arange(NU), indexing="ij")
        for k in range(n):  # B_k S on dv_k
            rows.append(NX * k + i4)
            cols.append(ucols[k][j4])
        for k in range(n):  # - dx_{k+1}
            rows.append(NX * k + np.arange(NX))
            cols.append(self.xcols[k])
            consts.append(-np.ones(NX))
        # Hessian (constant): W on dx_k, SLACK_WEIGHT on s_k, wu I + wd D^T D on the stacked dv
        diag = np.zeros(self.nvar)
        diag[self.xcols] = self.W
        diag[self.scols] = SLACK_WEIGHT
        diag[self.ucols] = weight_input + 2.0 * weight_input_rate
        diag[ucols[-1]] = weight_input + weight_input_rate  # the last input's change has no successor
        self._structure(ca, rows, cols, consts, diag, (ucols[1:].reshape(-1), ucols[:-1].reshape(-1)))

    def fill(self, qp, A, B, u_scale, X, x_ref, V, v_prev, lo, hi, qmax) -> None:
        """The QP's arguments into the solver instance's arrays."""
        self._fill_common(qp, A, B, u_scale, X, x_ref, V, lo, hi, qmax)
        dv = _differences(V, v_prev)
        dtd = dv.copy()  # D^T (D V - (v_prev, 0, ..))
        dtd[:-NU] -= dv[NU:]
        qp.named_args["g"][self.ucols] = self.wu * V + self.wd * dtd


def _sparsity_and_order(ca, rows: np.ndarray, cols: np.ndarray, nrow: int, ncol: int):
    """(CasADi Sparsity of the entries (rows, cols), the permutation that puts values given in the
    order of (rows, cols) into CasADi's column-major order of nonzeros)."""
    template = ca.DM.triplet(rows.tolist(), cols.tolist(), ca.DM(np.arange(1.0, rows.size + 1)), nrow, ncol)
    order = np.asarray(template.nonzeros(), dtype=np.int64) - 1
    if template.nnz() != rows.size or sorted(order.tolist()) != list(range(rows.size)):
        raise RuntimeError("the QP's structure has repeated entries")
    return template.sparsity(), order


class _Buffered:
    """A CasADi Function called on NumPy arrays it reads and writes in place (``Function.buffer``):
    CasADi's conversions of NumPy arrays to and from its matrices cost ~1 ms for a 100 x 100 matrix,
    more than the QP's solve. ``args[i]`` / ``res[i]``: the nonzeros of input / output i in CasADi's
    column-major order (a dense (r, c) matrix M is ``array.reshape(c, r)`` = M.T), also by name in
    ``named_args`` / ``named_res``.

    ``fresh_work``: every call gets a new buffer, i.e. zeroed work memory. CasADi's HPIPM interface
    (3.8) leaves state in its work memory from one call to the next (the second of two different QPs
    solved through one buffer came out wrong, by up to the whole thrust range; a plain Function call,
    which allocates its work anew, did not), so HPIPM is called this way (~15 us more per call)."""

    def __init__(self, fn, fresh_work: bool = False):
        self.fn = fn
        self.fresh_work = fresh_work
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self.named_args = {fn.name_in(i): a for i, a in enumerate(self.args)}
        self.named_res = {fn.name_out(i): r for i, r in enumerate(self.res)}
        self._bind()

    def _bind(self) -> None:
        self._buffer, self._eval = self.fn.buffer()
        for i, a in enumerate(self.args):
            self._buffer.set_arg(i, memoryview(a))
        for i, r in enumerate(self.res):
            self._buffer.set_res(i, memoryview(r))

    def __call__(self) -> int:
        """Evaluate; CasADi's return flag (0: no error raised by the Function)."""
        if self.fresh_work:
            self._bind()
        self._eval()
        return self._buffer.ret()

    def success(self) -> bool:
        """Whether the last call of a solver succeeded (its ``stats()["success"]``)."""
        return bool(self._buffer.stats().get("success", False))


class _PiqpQP:
    """PIQP's sparse solver (a proximal interior point method; its ``sparse_multistage`` KKT solver factors
    the OCP's block structure) on a QP given as CasADi's ``conic`` takes it, with the interface of
    :class:`_Buffered`: ``named_args`` h, g, a (the nonzeros of H and A in the column-major order of the
    sparsities), lba, uba, lbx, ubx, and ``named_res["x"]``.

    Rows with lba == uba at the first call (the dynamics) are PIQP's equalities, the others its two-sided
    inequalities; bounds at or beyond +-:data:`FREE_BOUND` are infinite for PIQP (unbounded, as they are meant).
    The first call sets the problem up (PIQP's symbolic analysis); later calls pass the new values. With
    PIQP's Ruiz scaling on (``preconditioner_iter`` > 0) a solve depended on the calls before it on the same
    instance (1e-10: the scaling is updated from the last one); the MPC runs it off, and a solve is then the
    same on a used instance as on a fresh one (tests/control/test_mpc.py)."""

    def __init__(self, sparsity: dict, settings: dict):
        import scipy.sparse as sp

        h_sp, a_sp = sparsity["h"], sparsity["a"]
        self._settings = dict(settings)
        self._h = sp.csc_matrix((np.zeros(h_sp.nnz()), np.array(h_sp.row()), np.array(h_sp.colind())),
                                shape=(h_sp.size1(), h_sp.size2()))
        # the nonzeros of A as an index into themselves, to split the rows once
        self._a_index = sp.csc_matrix((np.arange(1.0, a_sp.nnz() + 1), np.array(a_sp.row()),
                                       np.array(a_sp.colind())), shape=(a_sp.size1(), a_sp.size2()))
        nvar, nrow = h_sp.size1(), a_sp.size1()
        self.named_args = {"h": np.zeros(h_sp.nnz()), "g": np.zeros(nvar), "a": np.zeros(a_sp.nnz()),
                           "lba": np.zeros(nrow), "uba": np.zeros(nrow), "lbx": np.zeros(nvar),
                           "ubx": np.zeros(nvar)}
        self.named_res = {"x": np.zeros(nvar)}
        self._solver = None
        self._success = False

    def _setup(self) -> None:
        import piqp

        arg = self.named_args
        equal = arg["lba"] == arg["uba"]
        rows_eq, rows_in = np.flatnonzero(equal), np.flatnonzero(~equal)
        a_eq = self._a_index[rows_eq].tocsc()
        a_in = self._a_index[rows_in].tocsc()
        a_eq.sort_indices()
        a_in.sort_indices()
        self._rows_eq, self._rows_in = rows_eq, rows_in
        self._take_eq = a_eq.data.astype(np.int64) - 1
        self._take_in = a_in.data.astype(np.int64) - 1
        self._a_eq, self._a_in = a_eq, a_in
        self._h.data[:] = arg["h"]
        solver = piqp.SparseSolver()
        solver.settings.kkt_solver = piqp.KKTSolver.sparse_multistage
        for key, value in self._settings.items():
            setattr(solver.settings, key, value)
        self._solver = solver
        self._fill_values()
        solver.setup(self._h, arg["g"], a_eq, self._b, a_in, self._h_lo, self._h_hi, self._x_lo, self._x_hi)

    def _fill_values(self) -> None:
        arg = self.named_args
        np.take(arg["a"], self._take_eq, out=self._a_eq.data)
        np.take(arg["a"], self._take_in, out=self._a_in.data)
        self._b = arg["lba"][self._rows_eq]
        self._h_lo = _unbounded(arg["lba"][self._rows_in])
        self._h_hi = _unbounded(arg["uba"][self._rows_in])
        self._x_lo = _unbounded(arg["lbx"])
        self._x_hi = _unbounded(arg["ubx"])

    def __call__(self) -> int:
        """Solve; 0 (whether PIQP solved it: :meth:`success`)."""
        import piqp

        arg = self.named_args
        if self._solver is None:
            self._setup()
        else:
            if not np.array_equal(arg["lba"][self._rows_eq], arg["uba"][self._rows_eq]):
                raise ValueError("the QP's equality rows changed after its first solve; build a new instance")
            self._fill_values()
            hessian = None
            if not np.array_equal(arg["h"], self._h.data):
                self._h.data[:] = arg["h"]
                hessian = self._h
            self._solver.update(P=hessian, c=arg["g"], A=self._a_eq, b=self._b, G=self._a_in, h_l=self._h_lo,
                                h_u=self._h_hi, x_l=self._x_lo, x_u=self._x_hi)
        status = self._solver.solve()
        self.named_res["x"][:] = self._solver.result.x
        self._success = status == piqp.PIQP_SOLVED
        return 0

    def success(self) -> bool:
        """Whether the last solve ended with PIQP's status "solved"."""
        return self._success

    @property
    def iterations(self) -> int:
        """PIQP's iterations in the last solve."""
        return int(self._solver.result.info.iter)


def _unbounded(bounds: np.ndarray) -> np.ndarray:
    """The bounds with the entries at or beyond +-FREE_BOUND made infinite."""
    return np.where(np.abs(bounds) >= FREE_BOUND, np.copysign(np.inf, bounds), bounds)
