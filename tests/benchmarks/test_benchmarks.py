"""Fast paths vs reference paths (issue 7), and the benchmark script end to end (quick mode).

The fast paths: the SIMD lane kernels of the env's physics, the fused compiled controller step
(PassivityController, the residual mode, PassivityPolicy), the lazily bracketed exact allocation and
the thread split of large batches. The reference paths: the public per-piece API (dynamics,
integrators, passivity_control, allocate) composed in Python. They must agree to 1e-12 (they are the
same kernels, so in fact bit for bit). Nothing here is timed.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv, dynamics, integrators
from softpvtol_gym import model as MK
from softpvtol_gym._parallel import row_ranges
from softpvtol_gym.control import PassivityController, allocate, passivity_control, storage_function
from softpvtol_gym.control import _kernels as CK
from softpvtol_gym.control.closed_loop import LOOPS
from softpvtol_gym.envs.config import EnvConfig
from softpvtol_gym.envs.episodes import N_UNIFORMS, sample_episodes
from softpvtol_gym.params import PARAM_FIELDS
from softpvtol_gym.references import N_REF_PARAMS
from softpvtol_gym.tasks import BUILTIN_TASKS, HOVER_SETPOINT, PAPER_Q0

ROOT = Path(__file__).resolve().parents[2]
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
            arm = self.history[-1].copy()
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


# ---------------------------------------------------------------------------------- physics
@pytest.mark.parametrize("held", ["tau", "paper", "exact"])
@pytest.mark.parametrize("n", [1, 5, MK.LANES, 2 * MK.LANES + 5])
def test_rk4_lanes_match_public_rk4(n, held):
    """The lane kernel = the public RK4 step, for a held tau and for held actuators (both input maps)."""
    rng = np.random.default_rng(n)
    q = rng.uniform(-1, 1, (n, 5)) * [5, 5, 3, 2.5, 2.5]
    qd = rng.uniform(-3, 3, (n, 5))
    u = rng.uniform(-80, 80, (n, 5))
    ext = rng.uniform(-5, 5, (n, 2))
    if held != "tau":
        u[:, :2] = np.abs(u[:, :2])
        u[:, 4] = 0.0
    code = MK.HELD_TAU if held == "tau" else dynamics.input_map_code(held)
    Pm = P.array * rng.uniform(0.8, 1.2, (n, 10))
    L = MK.LANES
    for b in range(0, n, L):
        m = min(L, n - b)
        W = np.zeros(MK.LANE_ROWS_RK4 * L)
        for i in range(5):
            W[(MK.LANE_Q + i) * L:(MK.LANE_Q + i) * L + m] = q[b:b + m, i]
            W[(MK.LANE_QD + i) * L:(MK.LANE_QD + i) * L + m] = qd[b:b + m, i]
            W[(MK.LANE_U + i) * L:(MK.LANE_U + i) * L + m] = u[b:b + m, i]
        for i in range(2):
            W[(MK.LANE_EXT + i) * L:(MK.LANE_EXT + i) * L + m] = ext[b:b + m, i]
        for i in range(10):
            W[(MK.LANE_P + i) * L:(MK.LANE_P + i) * L + m] = Pm[b:b + m, i]
        MK.rk4_lanes(W, 0.01, m, code)
        for j in range(m):
            p = SoftPVTOLParams.from_array(Pm[b + j])
            if held == "tau":
                qn, vn = integrators.rk4_step(q[b + j], qd[b + j], u[b + j] + np.r_[ext[b + j], 0, 0, 0], p)
            else:
                qn, vn = integrators.rk4_step_actuated(q[b + j], qd[b + j], u[b + j, :4], p, 0.01, held, ext[b + j])
            np.testing.assert_allclose([W[(MK.LANE_Q + i) * L + j] for i in range(5)], qn, **TOL)
            np.testing.assert_allclose([W[(MK.LANE_QD + i) * L + j] for i in range(5)], vn, **TOL)


def test_vector_env_physics_matches_public_api():
    """One step of the compiled env (SIMD blocks + remainder) = rk4_step_actuated of the public API on
    the applied actuators (held); energy and storage in info = total_energy, storage_function."""
    n = 2 * MK.LANES + 5
    venv = SoftPVTOLVectorEnv(num_envs=n, tier="mismatch", task="setpoint")
    venv.reset(seed=3)
    sim = venv.sim
    rng = np.random.default_rng(0)
    for _ in range(3):
        q0, qd0, Pm = sim.q.copy(), sim.qd.copy(), sim.P.copy()
        _, _, term, _, info = venv.step(rng.uniform(-0.3, 0.3, (n, 4)))
        a = sim.applied[:, :4]
        for i in range(n):
            p = SoftPVTOLParams.from_array(Pm[i])
            q1, v1 = integrators.rk4_step_actuated(q0[i], qd0[i], a[i], p, 0.01)
            np.testing.assert_allclose(sim.q[i], q1, **TOL)
            np.testing.assert_allclose(sim.qd[i], v1, **TOL)
            np.testing.assert_allclose(info["total_energy"][i], dynamics.total_energy(q1, v1, p), **TOL)
            qr = np.r_[sim.qr[i, :3], 0, 0]
            qdr = np.r_[sim.qdr[i, :3], 0, 0]
            np.testing.assert_allclose(info["storage_function"][i], storage_function(q1, v1, qr, qdr, P), **TOL)
        assert not term.any()


def test_large_vector_env_subenvs_equal_single_envs():
    """Threads + SIMD blocks (600 envs) vs single envs seeded s + i, residual mode, hard tier."""
    n, s = 600, 5
    kw = dict(action_mode="residual", tier="hard", task="track_random")
    venv = SoftPVTOLVectorEnv(num_envs=n, **kw)
    assert venv._sim._ranges == row_ranges(n, align=MK.LANES)
    picks = [0, MK.LANES - 1, MK.LANES, 301, n - 1]
    singles = {i: SoftPVTOLEnv(**kw) for i in picks}
    vo, _ = venv.reset(seed=s)
    for i, e in singles.items():
        np.testing.assert_array_equal(vo[i], e.reset(seed=s + i)[0])
    rng = np.random.default_rng(0)
    for _ in range(25):
        a = rng.uniform(-1, 1, (n, 5))
        vo, vr, vt, vtr, _ = venv.step(a)
        for i, e in singles.items():
            o, r, t, tr, _ = e.step(a[i])
            np.testing.assert_array_equal(vo[i], o)
            assert vr[i] == r and vt[i] == t and vtr[i] == tr
            if t or tr:
                e.reset()  # the vector env resets it at its next step: compare until then only
                singles = {k: v for k, v in singles.items() if k != i}


def test_thread_split_equals_one_call():
    rng = np.random.default_rng(1)
    n = 1500
    q = rng.uniform(-1, 1, (n, 5))
    qd = rng.uniform(-1, 1, (n, 5))
    tau = rng.uniform(-20, 20, (n, 5))
    whole = dynamics.forward_dynamics(q, qd, tau, P)
    parts = np.concatenate([dynamics.forward_dynamics(q[i:i + 100], qd[i:i + 100], tau[i:i + 100], P)
                            for i in range(0, n, 100)])
    np.testing.assert_array_equal(whole, parts)
    ctrl = PassivityController.from_loop("improved")
    small = [PassivityController.from_loop("improved") for _ in range(3)]
    for _ in range(3):
        out = ctrl(q, qd, 0 * q, 0 * q, 0 * q)
        for j, c in enumerate(small):
            sl = slice(500 * j, 500 * j + 500)
            zero = 0 * q[sl]
            np.testing.assert_array_equal(out.actuators[sl], c(q[sl], qd[sl], zero, zero, zero).actuators)


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


# ------------------------------------------------------------------------- episode sampling
def _numpy_sample_episodes(cfg, u):
    """The episode sampling written with numpy array operations (the pre-compilation version)."""
    n = u.shape[0]
    c = 2.0 * u - 1.0  # in [-1, 1)
    refp = np.zeros((n, N_REF_PARAMS))
    q0 = np.zeros((n, 5))
    qd0 = np.zeros((n, 5))
    # perturbation used by hover / setpoint / track_random: (c0, c1, 0.3 c2, 0.3 c3, 0.3 c4) and
    # (0.5 c5, 0.5 c6, 0.2 c7, 0.2 c8, 0.2 c9) (x 1.0 is exact)
    dq = c[:, 0:5] * np.array([1.0, 1.0, 0.3, 0.3, 0.3])
    dqd = c[:, 5:10] * np.array([0.5, 0.5, 0.2, 0.2, 0.2])
    task = cfg.task
    if task == "hover":
        refp[:, :3] = HOVER_SETPOINT
        q0[:, :3] = HOVER_SETPOINT
        q0 += dq
        qd0 = dqd
    elif task == "setpoint":
        refp[:, 0] = 3.0 * c[:, 10]
        refp[:, 1] = 2.0 + 2.0 * c[:, 11]
        refp[:, 2] = 0.3 * c[:, 12]
        q0[:, 0] = 3.0 * c[:, 0]
        q0[:, 1] = 2.0 + 2.0 * c[:, 1]
        q0[:, 2:] = dq[:, 2:]
        qd0 = dqd
    elif task == "track_paper":
        q0[:] = PAPER_Q0
    else:
        refp[:, 1] = 3.0  # z0
        for axis, amax in ((0, 1.0), (1, 0.5)):
            b = 3 + 9 * axis
            refp[:, b:b + 3] = amax * u[:, 13 + 9 * axis:16 + 9 * axis]
            refp[:, b + 3:b + 6] = 0.2 + 0.6 * u[:, 16 + 9 * axis:19 + 9 * axis]
            refp[:, b + 6:b + 9] = 2.0 * math.pi * u[:, 19 + 9 * axis:22 + 9 * axis]
        # the reference at t = 0: x = 0, z = z0, rates sum_k A_k w_k cos(phi_k)
        r0, rd0 = np.zeros((n, 5)), np.zeros((n, 5))
        r0[:, 1] = refp[:, 1]
        for axis in range(2):
            b = 3 + 9 * axis
            rd0[:, axis] = (refp[:, b:b + 3] * refp[:, b + 3:b + 6] * np.cos(refp[:, b + 6:b + 9])).sum(axis=1)
        q0 = r0 + 0.5 * dq
        qd0 = rd0 + 0.5 * dqd
    P = np.repeat(cfg.params.array[None, :], n, axis=0)
    s = cfg.mismatch_scale
    if s > 0:
        idx = [PARAM_FIELDS.index(f) for f in ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")]
        P[:, idx] *= 1.0 + s * c[:, 31:39]
    key = (u[:, 46] * 2.0**53).astype(np.uint64) ^ ((u[:, 47] * 2.0**53).astype(np.uint64) << np.uint64(11))
    return dict(q0=q0, qd0=qd0, refp=refp, P=np.ascontiguousarray(P), key=key)


@pytest.mark.parametrize("task", BUILTIN_TASKS)
@pytest.mark.parametrize("tier", ["nominal", "mismatch", "hard"])
def test_compiled_episode_sampling_equals_numpy_version(task, tier):
    cfg = EnvConfig(task=task, tier=tier)
    u = np.random.default_rng(5).random((200, N_UNIFORMS))
    u[:3] = 0.0
    u[3:6] = np.nextafter(1.0, 0.0)
    ref, fast = _numpy_sample_episodes(cfg, u), sample_episodes(cfg, u)
    assert ref.keys() == fast.keys()
    for k in ref:
        assert ref[k].dtype == fast[k].dtype and ref[k].shape == fast[k].shape
        assert ref[k].tobytes() == fast[k].tobytes(), k


# ------------------------------------------------------------------------- benchmark script
@pytest.mark.slow  # benchmarks/run.py --quick in a subprocess
def test_benchmark_script_runs_end_to_end_quick(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(tmp_path)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    md = (tmp_path / "RESULTS.md").read_text()
    data = json.loads((tmp_path / "results.json").read_text())
    assert set(data["items"]) == {"single", "vector", "controller", "ppo", "cold_start", "time_to_beat"}
    for item in data["items"].values():
        assert item["targets"] and all(isinstance(t["pass"], bool) for t in item["targets"].values())
    for key in ("cores", "python", "numpy", "numba", "gymnasium", "torch", "stable_baselines3", "commit"):
        assert key in data["machine"]
    for title in ("1. Single-env", "2. Vector-env", "3. Passivity controller", "4. PPO", "5. Cold start",
                  "6. Time to beat"):
        assert title in md
    item = data["items"]["time_to_beat"]  # a short train.py run: its curve, passivity's line and the plot
    assert item["curve"][0]["step"] == 0 and item["total_seconds"] > item["curve"][-1]["seconds"] > 0
    assert (tmp_path / "time_to_beat.png").stat().st_size > 10_000
    assert "Pendulum-v1" in md and "CartPoleVectorEnv" in md and "do not edit" in md


@pytest.mark.parametrize("n", [1, 3])
@pytest.mark.parametrize("loop", ["exact", "integral", "extended", "controller"])
def test_benchmark_replays_each_controller_along_its_own_closed_loop(n, loop):
    """Item 3 times copies of a controller replaying the calls of its closed loop: each window's replay gives the
    loop's outputs bit for bit, so the timed calls are the loop's (and where the outputs depend on the memory, a
    replay from the wrong window's copy does not)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from benchmarks._env_speed import _ClosedLoop

    if loop == "controller":
        env = SoftPVTOLVectorEnv(num_envs=n, action_mode="residual", task="hover", tier="nominal")
        policy = PassivityController.from_loop("exact")
    else:
        env = SoftPVTOLVectorEnv(num_envs=n, task="hover", tier="nominal")
        policy = PassivityPolicy.from_env(env, loop=loop)
    closed = _ClosedLoop(env, policy, (0, 6), 3, single=n == 1)
    assert [len(calls) for _, calls, _ in closed.windows] == [3, 3]
    for snapshot, calls, outputs in closed.windows:
        fn = closed.caller(snapshot)
        for call, want in zip(calls, outputs, strict=True):
            got = closed.output(fn(*call))
            assert got.shape == ((4,) if n == 1 else (n, 4)) and got.tobytes() == want.tobytes()
    if loop in ("integral", "extended"):  # (the exact loop's outputs do not depend on its memory's warm start)
        wrong = closed.caller(closed.windows[0][0])  # the start's copy on the second window's calls
        (_, calls, outputs) = closed.windows[1]
        assert any(closed.output(wrong(*c)).tobytes() != w.tobytes() for c, w in zip(calls, outputs))
    assert closed.timer()() > 0.0


def test_readme_performance_table_is_the_generated_one():
    """The table of the measurements (benchmarks/README.md, where benchmarks/run.py writes it) = benchmarks/run.py's
    table from the committed results.json."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_benchmarks_run", ROOT / "benchmarks" / "run.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    payload = json.loads((ROOT / "benchmarks" / "results.json").read_text())
    assert bench.README == ROOT / "benchmarks" / "README.md"
    text = bench.README.read_text()
    block = text[text.index(bench.README_START) + len(bench.README_START):text.index(bench.README_END)]
    assert block.strip() == bench.readme_table(payload).strip()
    assert not payload["quick"]


def _train_block(text: str) -> list[str]:
    """The lines of the README's block that shows what `python train.py` prints."""
    start = text.index("```\nPPO vs passivity")
    return text[start + 4:text.index("```", start + 4)].strip().splitlines()


def test_readme_train_py_output_and_time_to_beat_are_the_committed_measurement():
    """The README's `python train.py` output is what the committed benchmark's train.py run printed (the run
    directory aside), its time to beat passivity is the first evaluation above passivity on the committed
    learning curve, and the committed learning-curve PNG exists."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_benchmarks_run", ROOT / "benchmarks" / "run.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    item = json.loads((ROOT / "benchmarks" / "results.json").read_text())["items"]["time_to_beat"]
    printed = [line for line in item["stdout"].strip().splitlines() if line.strip()]
    block = _train_block((ROOT / "README.md").read_text())
    assert block[0].split("; run in ")[0] == printed[-4].split("; run in ")[0]
    assert block[1:] == printed[-3:]
    assert item["command"] == "python train.py --no-progress-bar"  # the default agent, nothing changed
    curve = [{"step": e["step"], "wall_time": e["seconds"], "mean_return": e["mean_return"],
              "mean_rms_position_error": e["mean_rms_position_error"]} for e in item["curve"]]
    beat = bench.time_to_beat(curve, item["passivity"]["mean_return"], 0.0)
    assert beat == item["beat"] and beat is not None
    assert all(e["mean_return"] <= item["passivity"]["mean_return"] for e in curve if e["step"] < beat["step"])
    png = (ROOT / "benchmarks" / "time_to_beat.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_docs_ppo_speed_table_is_the_generated_one():
    """docs/baselines.md's "Fast defaults" table = benchmarks/ppo_speed.py --table of the committed JSON, and
    every run's steps to beat is the first evaluation above passivity on its committed learning curve."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_ppo_speed", ROOT / "benchmarks" / "ppo_speed.py")
    speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed)
    results = json.loads((ROOT / "benchmarks" / "ppo_speed.json").read_text())
    text = (ROOT / "docs" / "baselines.md").read_text()
    start = "<!-- benchmarks/ppo_speed.py --table: start (generated from benchmarks/ppo_speed.json, do not edit) -->"
    block = text[text.index(start) + len(start):text.index("<!-- benchmarks/ppo_speed.py --table: end -->")]
    assert block.strip() == speed.markdown_table(results).strip()
    for r in results:
        above = [e for e in r["curve"] if e["mean_return"] > r["passivity"]["mean_return"]]
        assert r["steps_to_beat"] == (above[0]["step"] if above else None)
        assert r["command"].startswith("python benchmarks/ppo_speed.py ")


def _ppo_speed_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("softpvtol_ppo_speed", ROOT / "benchmarks" / "ppo_speed.py")
    speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed)
    return speed


def test_fast_recipe_comparison_is_the_committed_runs_and_the_docs_table():
    """Issue 26, goal 4: benchmarks/ppo_speed_fast.json holds the default entry and the residual-fast recipe as
    shipped, five seeds each on the tracking cell; benchmarks/README.md's table is --compare's output for it."""
    from softpvtol_gym.baselines.config.recipes import load_recipe

    speed = _ppo_speed_module()
    results = json.loads((ROOT / "benchmarks" / "ppo_speed_fast.json").read_text())
    assert {(r["name"], r["seed"]) for r in results} == {(n, s) for n in ("default", "fast") for s in range(5)}
    for r in results:
        assert (r["action_mode"], r["task"], r["tier"]) == ("residual", "track_random", "nominal")
        assert r["overrides"] == ([] if r["name"] == "default" else load_recipe("residual-fast")["hp"])
        assert r["command"].startswith("python benchmarks/ppo_speed.py ")
        assert r["final"] == r["curve"][-1] and r["timesteps"] >= 1_000_000
    cmp = speed.compare(results, "default", "fast")
    assert cmp["seeds"] == [0, 1, 2, 3, 4] and set(cmp["checks"]) and cmp["passed"] is all(cmp["checks"].values())
    text = (ROOT / "benchmarks" / "README.md").read_text()
    start = ("<!-- benchmarks/ppo_speed.py --compare: start (generated from benchmarks/ppo_speed_fast.json, do not "
             "edit) -->")
    block = text[text.index(start) + len(start):text.index("<!-- benchmarks/ppo_speed.py --compare: end -->")]
    assert block.strip() == speed.compare_table(results, "default", "fast").strip()
    png = (ROOT / "benchmarks" / "ppo_speed_fast.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_ppo_speed_compare_checks_each_criterion():
    speed = _ppo_speed_module()

    def run(name, seed, rms, ret, wall, rate, rate_no_eval, task="track_random"):
        final = {"step": 1000, "seconds": wall, "mean_return": ret, "mean_rms_position_error": rms, "crash_rate": 0.0}
        return {"name": name, "seed": seed, "action_mode": "residual", "task": task, "tier": "nominal",
                "hyperparams": {}, "timesteps": 1000, "final": final, "wall_seconds": wall, "steps_per_second": rate,
                "steps_per_second_without_evaluations": rate_no_eval, "loadavg_before": [1.0, 1.0, 1.0]}

    base = [run("a", s, 0.07, 1900.0, 60.0, 15e3, 16e3) for s in (0, 1)]
    good = [run("b", s, 0.06, 1910.0, 19.0, 52e3, 55e3) for s in (0, 1)]
    assert speed.compare(base + good, "a", "b")["passed"]
    for bad, failed in (({"rms": 0.08}, "final RMS error at most the baseline's"),
                        ({"ret": 1800.0}, "final return at least the baseline's"),
                        ({"wall": 21.0}, "wall time at most a third of the baseline's"),
                        ({"rate_no_eval": 49e3}, "at least 50 k env-steps/s, rollouts and updates")):
        kw = {"rms": 0.06, "ret": 1910.0, "wall": 19.0, "rate": 52e3, "rate_no_eval": 55e3, **bad}
        cmp = speed.compare(base + [run("b", s, **kw) for s in (0, 1)], "a", "b")
        assert not cmp["passed"] and [k for k, ok in cmp["checks"].items() if not ok] == [failed]
    with pytest.raises(SystemExit, match="no run named 'c'"):
        speed.compare(base, "a", "c")
    with pytest.raises(SystemExit, match="not the same cell"):
        speed.compare(base + [run("b", 0, 0.06, 1910.0, 19.0, 52e3, 55e3, task="hover")], "a", "b")


def test_ppo_speed_config_of_a_recipe_is_its_hp_and_must_match_the_mode():
    from softpvtol_gym.baselines.config.recipes import load_recipe

    speed = _ppo_speed_module()
    assert speed.parse_config("fast=recipe:residual-fast", "residual") == ("fast", load_recipe("residual-fast")["hp"])
    with pytest.raises(SystemExit, match="the recipe is for the residual mode, this run's --mode is actuators"):
        speed.parse_config("fast=recipe:residual-fast", "actuators")
    with pytest.raises(SystemExit, match="hp overrides only"):
        speed.parse_config("x=recipe:residual-precise", "residual")
    assert speed.parse_config("a=n_epochs=3;batch_size=64", "residual") == ("a", ["n_epochs=3", "batch_size=64"])
