"""The controller's fast paths against readable references: the fused compiled controller step
(PassivityController, the residual mode, PassivityPolicy) against the public per-piece API (passivity_control,
allocate) composed in Python, the lazily bracketed exact allocation against the eager bracket, the lane
allocation against the scalar one, and a controller row independent of its block. They must agree to 1e-12
(they are the same kernels, so in fact bit for bit). Nothing here is timed.
"""

import math

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLParams, SoftPVTOLVectorEnv, dynamics
from softpvtol_gym import model as MK
from softpvtol_gym.control import PassivityController, allocate, passivity_control
from softpvtol_gym.control import kernels as CK
from softpvtol_gym.control.closed_loop import LOOPS

P = SoftPVTOLParams()
TOL = dict(rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------- reference controller
class ReferenceController:
    """The actuated passivity controller composed from the public per-piece API in Python (the
    pre-fusion implementation): body rows of passivity_control -> allocate -> arm rows."""

    def __init__(self, loop, input_map="paper", algebraic_iterations=100, dt=0.01, tol=1e-10):
        self.allocation = LOOPS[loop]["allocation"]
        self.ff = LOOPS[loop]["arm_feedforward"]
        self.limits = LOOPS[loop].get("feedforward_limits", (5.0, 50.0))
        self.qmax = LOOPS[loop].get("curvature_limit", np.pi)
        self.input_map, self.iters, self.dt = input_map, algebraic_iterations, dt
        self.tol = tol
        self.history = self.warm = self.reseed = None

    def reset(self, mask=None):
        if mask is None or self.history is None:
            self.history = self.warm = self.reseed = None
            return
        self.reseed = mask if self.reseed is None else (self.reseed | mask)
        if self.warm is not None:
            self.warm[mask] = np.nan

    def _derivatives(self):
        h = self.history
        if not self.ff:
            return np.zeros_like(h[-1]), np.zeros_like(h[-1])
        dt, (vmax, amax) = self.dt, self.limits
        vel = np.clip((3.0 * h[-1] - 4.0 * h[-2] + h[-3]) / (2.0 * dt), -vmax, vmax)
        acc = np.clip((2.0 * h[-1] - 5.0 * h[-2] + 4.0 * h[-3] - h[-4]) / (dt * dt), -amax, amax)
        return vel, acc

    def __call__(self, q, qd, q_ref, qd_ref, qdd_ref, res=None, commit=True):
        q_ref, qd_ref, qdd_ref = (np.array(np.broadcast_to(r, q.shape), dtype=float) for r in (q_ref, qd_ref, qdd_ref))
        if self.history is None:
            arm, arm_d, arm_dd = q[..., 3:5].copy(), np.zeros_like(q[..., 3:5]), np.zeros_like(q[..., 3:5])
        else:
            arm = 2.0 * self.history[-1] - self.history[-2]  # the last two solutions extrapolated
            arm_d, arm_dd = self._derivatives()
            if self.reseed is not None:
                arm[self.reseed] = q[..., 3:5][self.reseed]
                arm_d[self.reseed] = 0.0
                arm_dd[self.reseed] = 0.0
        warm = self.warm
        # the algebraic loop, row by row: passes until the allocated curvatures move by <= tol; a row
        # whose change grew has its step halved (relaxation >= 1/1024); finished rows keep their values
        n = q.shape[0]
        live, relax, last = np.ones(n, bool), np.ones(n), np.full(n, np.inf)
        tau = alloc = info = None
        for it in range(1, self.iters + 1):
            # the body rows see the arm references without their fed-forward derivatives
            q_ref[..., 3:5], qd_ref[..., 3:5], qdd_ref[..., 3:5] = arm, 0.0, 0.0
            tau_it = passivity_control(q, qd, q_ref, qd_ref, qdd_ref, P)
            if res is not None:
                tau_it = tau_it + res
            alloc_it, info_it = allocate(tau_it, q, P, self.allocation, input_map=self.input_map, warm_start=warm,
                                         return_info=True, **({} if self.allocation == "paper" else
                                                              dict(curvature_limit=self.qmax)))
            if tau is None:
                tau, alloc, info = tau_it.copy(), alloc_it.copy(), info_it
            tau[live], alloc[live] = tau_it[live], alloc_it[live]
            for field in ("residual", "iterations", "feasible"):
                getattr(info, field)[live] = getattr(info_it, field)[live]
            warm = alloc.copy()
            change = np.max(np.abs(alloc_it[..., 2:4] - arm), axis=-1)
            done = live & ((change <= self.tol) | (it == self.iters))
            grew = live & ~done & (change > last)
            relax[grew] = np.maximum(0.5 * relax[grew], 1.0 / 1024.0)
            relax[done] = 1.0
            last[live] = change[live]
            step = live & (relax == 1.0)
            damped = live & (relax != 1.0)
            arm = arm.copy()
            arm[step] = alloc_it[step, 2:4]
            arm[damped] = arm[damped] + relax[damped, None] * (alloc_it[damped, 2:4] - arm[damped])
            live &= ~done
            if not live.any():
                break
        if commit:
            self.warm = alloc.copy()
            if self.history is None:
                self.history = [arm.copy() for _ in range(4)]
            else:
                self.history = self.history[1:] + [arm.copy()]
                if self.reseed is not None:
                    for h in self.history[:-1]:
                        h[self.reseed] = arm[self.reseed]
            self.reseed = None
            arm_d, arm_dd = self._derivatives()
        q_ref[..., 3:5], qd_ref[..., 3:5], qdd_ref[..., 3:5] = arm, arm_d, arm_dd
        tau_arm = passivity_control(q, qd, q_ref, qd_ref, qdd_ref, P)[..., 3:5]
        if res is not None:
            tau_arm = tau_arm + res[..., 3:5]
        act = np.concatenate([alloc[..., :2], tau_arm], axis=-1)
        if self.input_map == "exact":
            thrust = act.copy()
            thrust[..., 2:4] = 0.0
            act[..., 2:4] -= dynamics.generalized_forces(q, thrust, P, "exact")[..., 3:5]
        tau_cmd = tau.copy()
        tau_cmd[..., 3:5] = tau_arm
        return tau_cmd, act, arm, info


@pytest.mark.parametrize("loop, input_map, iters, tol", [
    ("exact", "paper", 1, 1e-10), ("paper", "paper", 1, 1e-10), ("improved", "exact", 1, 1e-10),
    ("improved", "paper", 3, 0.0), ("exact", "paper", 100, 1e-10), ("paper", "paper", 100, 1e-10),
    ("improved", "exact", 100, 1e-10), ("improved", "paper", 7, 1e-6), ("bounded", "paper", 100, 1e-10),
    ("bounded", "exact", 100, 1e-10)])
def test_fused_controller_matches_per_piece_reference(loop, input_map, iters, tol):
    rng = np.random.default_rng(0)
    n = 40
    fast = PassivityController.from_loop(loop, input_map=input_map, algebraic_iterations=iters,
                                         algebraic_tolerance=tol)
    ref = ReferenceController(loop, input_map=input_map, algebraic_iterations=iters, tol=tol)
    q = rng.uniform(-1, 1, (n, 5)) * [3, 3, 1, 0.8, 0.8]
    qd = rng.uniform(-1, 1, (n, 5))
    refs = [rng.uniform(-1, 1, (n, 5)) for _ in range(3)]
    for k in range(10):
        q = q + 0.01 * qd
        res = rng.uniform(-2, 2, (n, 5)) if k % 3 == 1 else None
        commit = k % 4 != 2
        if k == 6:
            mask = rng.random(n) < 0.3
            fast.reset(mask)
            ref.reset(mask)
        out = fast(q, qd, *refs, tau_residual=res, commit=commit)
        tau, act, arm, info = ref(q, qd, *refs, res=res, commit=commit)
        np.testing.assert_allclose(out.tau, tau, **TOL)
        np.testing.assert_allclose(out.actuators, act, **TOL)
        np.testing.assert_allclose(out.arm_reference, arm, **TOL)
        np.testing.assert_allclose(out.allocation.residual, info.residual, **TOL)
        np.testing.assert_array_equal(out.allocation.iterations, info.iterations)


def test_residual_env_and_policy_run_the_fused_controller():
    """Residual action 0 in the vector env = the reference controller on the measured state; the
    policy's compiled pass = the reference controller on its state from the observation."""
    n = 70
    venv = SoftPVTOLVectorEnv(num_envs=n, action_mode="residual", tier="mismatch", actuator_limits=(1e6, 1e6))
    venv.reset(seed=1)
    ref = ReferenceController(venv.config.resolved_controller_loop)
    sim = venv._sim
    for _ in range(5):
        _, act, _, _ = ref(sim.qm.copy(), sim.qdm.copy(), sim.qr.copy(), sim.qdr.copy(), sim.qddr.copy())
        _, _, term, trunc, _ = venv.step(np.zeros((n, 5)))
        assert not (term | trunc).any()
        np.testing.assert_allclose(sim.applied[:, :4], act, **TOL)  # no saturation, no lag
    env = SoftPVTOLVectorEnv(num_envs=n, action_mode="actuators", task="track_random", actuator_limits=(102.9, 1e3))
    pol = PassivityPolicy.from_env(env)
    ref = ReferenceController(pol.loop)
    obs, _ = env.reset(seed=2)
    for _ in range(5):
        a, _ = pol.predict(obs)
        _, act, _, _ = ref(*PassivityPolicy.state_from_observation(obs))
        u = np.clip(np.concatenate([2.0 * act[:, :2] / pol._tmax - 1.0, act[:, 2:4] / pol._taumax], axis=1), -1, 1)
        np.testing.assert_allclose(a, u.astype(np.float32), rtol=0, atol=1e-7)
        obs, *_ = env.step(a)


# ------------------------------------------------------------------------- lazy bracket
def _eager_exact_allocation(tau, theta, p, imap, warm, use_warm, qmax=math.pi):
    """The exact allocation with its bracket widened up front (the pre-optimisation algorithm)."""
    lever = CK._lever
    ll, lr, eps = p[6], p[7], p[9]
    ct, st = math.cos(theta), math.sin(theta)
    ux, uz, tt = ct * tau[0] + st * tau[1], -st * tau[0] + ct * tau[1], tau[2]
    h = 0.5 * ux
    scale = 1.0 + abs(uz) + abs(ux) + abs(tt)
    lo = -scale * (1.0 + 1.0 / min(ll, lr))
    hi = -lo
    for _ in range(60):
        if lever(uz - lo, -h, lr, eps, imap)[0] - lever(lo, h, ll, eps, imap)[0] - tt > 0.0:
            break
        lo *= 2.0
    for _ in range(60):
        if lever(uz - hi, -h, lr, eps, imap)[0] - lever(hi, h, ll, eps, imap)[0] - tt < 0.0:
            break
        hi *= 2.0
    x = 0.5 * uz
    if use_warm and math.isfinite(warm[0] + warm[2]):
        x = warm[0] * math.cos(warm[2])
    if not (lo < x < hi):
        x = 0.5 * (lo + hi)
    for _ in range(1, 101):
        Gl, dGl, _, _ = lever(x, h, ll, eps, imap)
        Gr, dGr, _, _ = lever(uz - x, -h, lr, eps, imap)
        F = Gr - Gl - tt
        if abs(F) <= 1e-13 * scale:
            break
        if F > 0.0:
            lo = x
        else:
            hi = x
        dF = -dGr - dGl
        xn = x - F / dF if dF < 0.0 else 0.5 * (lo + hi)
        if not (lo < xn < hi):
            xn = 0.5 * (lo + hi)
        if abs(xn - x) <= 1e-16 * (1.0 + abs(x)):
            x = xn
            break
        x = xn
    ql, qr = math.atan2(h, x), math.atan2(-h, uz - x)
    ql, qr = min(max(ql, -qmax), qmax), min(max(qr, -qmax), qmax)
    return math.hypot(h, x), math.hypot(h, uz - x), ql, qr


@pytest.mark.parametrize("imap", ["paper", "exact"])
def test_lazy_bracket_gives_the_eager_bracket_solution(imap):
    rng = np.random.default_rng(7)
    n = 300
    tau = rng.standard_cauchy((n, 3)) * 10.0 ** rng.integers(-2, 5, (n, 1))
    q = np.zeros((n, 5))
    q[:, 2] = rng.uniform(-3, 3, n)
    warm = np.where(rng.random((n, 1)) < 0.5, rng.standard_cauchy((n, 4)) * 100, np.nan)
    fast = allocate(tau, q, P, "exact", input_map=imap, warm_start=warm)
    code = MK.INPUT_MAP_PAPER if imap == "paper" else MK.INPUT_MAP_EXACT
    for i in range(n):
        ref = _eager_exact_allocation(tau[i], q[i, 2], P.array, code, warm[i], True)
        np.testing.assert_allclose(fast[i], ref, **TOL)


# ------------------------------------------------------------------------- lane allocation
@pytest.mark.parametrize("imap", [MK.INPUT_MAP_PAPER, MK.INPUT_MAP_EXACT])
@pytest.mark.parametrize("m", [1, 7, CK.CTRL_LANES])
def test_lane_allocation_equals_scalar_allocation_bit_for_bit(imap, m):
    """allocate_exact_lanes (the controller's interleaved Newton) = allocate_exact lane by lane, on
    heavy-tailed forces, cold and wild warm starts, clipped curvatures; inactive lanes untouched. As the
    algebraic loop's later passes call it (theta's sin and cos from the call before, the residual left NaN and
    computed once by allocation_residual), the results are the same."""
    rng = np.random.default_rng(m + 100 * imap)
    L, p = CK.CTRL_LANES, tuple(P.array)
    for trial in range(25):
        tau = rng.standard_cauchy((3, L)) * 10.0 ** rng.integers(-2, 5, (1, L))
        theta = rng.uniform(-3, 3, L)
        warm = np.where(rng.random(L) < 0.5, rng.standard_cauchy((4, L)) * 100, np.nan)
        active = (rng.random(L) < 0.8).astype(float)
        qmax = math.pi if trial % 2 else 0.5
        # the flat lane block: rows tau (0-2), theta (3), warm start (4-7), active (8), out (9-12), info (13-15)
        X = np.concatenate([tau, theta[None], warm, active[None], np.full((4 + CK.N_INFO, L), -7.0)]).ravel()
        A = np.zeros(CK.N_AW * L)
        X0 = X.copy()
        CK.allocate_exact_lanes(m, X, 0, 3, 4, 8, 9, 13, A, True, p, imap, qmax)
        # an algebraic loop's later pass: theta's sin and cos kept in A from the call before, no residual
        X0[4 * L:8 * L] = np.where(rng.random(L) < 0.5, X0[4 * L:8 * L].reshape(4, L), np.nan).ravel()
        X1 = X0.copy()
        CK.allocate_exact_lanes(m, X0, 0, 3, 4, 8, 9, 13, np.zeros(CK.N_AW * L), True, p, imap, qmax)
        CK.allocate_exact_lanes(m, X1, 0, 3, 4, 8, 9, 13, A, True, p, imap, qmax, True, False)
        X, X0, X1 = X.reshape(-1, L), X0.reshape(-1, L), X1.reshape(-1, L)
        out, info = X[9:13], X[13:16]
        for j in range(L):
            if j < m and active[j]:
                o, i = CK.allocate_exact(tau[0, j], tau[1, j], tau[2, j], theta[j], p, imap, warm[0, j], warm[2, j],
                                         True, qmax)
                np.testing.assert_array_equal(out[:, j], o)
                np.testing.assert_array_equal(info[:, j], i)
                np.testing.assert_array_equal(X1[9:13, j], X0[9:13, j])
                np.testing.assert_array_equal(X1[14:16, j], X0[14:16, j])
                assert np.isnan(X1[13, j])
                st, ct = math.sin(theta[j]), math.cos(theta[j])
                Tl, Tr, ql, qr = X1[9:13, j]
                assert CK.allocation_residual(st, ct, ql, qr, Tl, Tr, *tau[:, j], p, imap) == X0[13, j]
            else:
                assert (out[:, j] == -7.0).all() and (info[:, j] == -7.0).all()
                assert (X1[9:16, j] == -7.0).all()


@pytest.mark.parametrize("loop", ["exact", "paper", "improved"])
def test_controller_row_does_not_depend_on_its_block(loop):
    """Rows computed in lane blocks: a permuted batch gives the permuted results, bit for bit."""
    rng = np.random.default_rng(3)
    n = 2 * CK.CTRL_LANES + 5
    q, qd, qr, qdr, qddr = (rng.uniform(-1, 1, (n, 5)) for _ in range(5))
    perm = rng.permutation(n)
    a, b = PassivityController.from_loop(loop), PassivityController.from_loop(loop)
    for k in range(3):
        res = rng.uniform(-1, 1, (n, 5)) if k == 1 else None
        oa = a(q, qd, qr, qdr, qddr, tau_residual=res)
        ob = b(q[perm], qd[perm], qr[perm], qdr[perm], qddr[perm], tau_residual=None if res is None else res[perm])
        for f in ("tau", "actuators", "arm_reference"):
            np.testing.assert_array_equal(getattr(oa, f)[perm], getattr(ob, f))
        np.testing.assert_array_equal(oa.allocation.iterations[perm], ob.allocation.iterations)
        q = q + 0.01 * qd


@pytest.mark.parametrize("loop", ["exact", "paper", "improved"])
def test_single_state_fast_path_equals_a_batch_of_one(loop):
    rng = np.random.default_rng(4)
    one, batch = PassivityController.from_loop(loop), PassivityController.from_loop(loop)
    q, qd, qr, qdr, qddr = (rng.uniform(-1, 1, 5) for _ in range(5))
    for k in range(4):
        res = rng.uniform(-1, 1, 5) if k == 2 else None
        o1 = one(q, qd, qr, qdr, qddr, tau_residual=res, commit=k != 1)
        ob = batch(*(x[None] for x in (q, qd, qr, qdr, qddr)), tau_residual=None if res is None else res[None],
                   commit=k != 1)
        for f in ("tau", "actuators", "arm_reference"):
            assert getattr(o1, f).shape == getattr(ob, f).shape[1:]
            np.testing.assert_array_equal(getattr(o1, f), getattr(ob, f)[0])
        for f in ("residual", "iterations", "feasible"):
            v1, vb = getattr(o1.allocation, f), getattr(ob.allocation, f)
            assert v1.shape == () and v1.dtype == vb.dtype
            np.testing.assert_array_equal(v1, vb[0])
        q = q + 0.01 * qd
    memory = one._state.copy()
    with pytest.raises(ValueError, match="NaN or inf"):
        one(np.full(5, np.nan), qd, qr, qdr, qddr)
    np.testing.assert_array_equal(one._state, memory)  # a failed call changes nothing
