"""The env's fast paths against readable references: the SIMD lane kernels of the physics against the public
RK4 (dynamics, integrators), the vector env's physics and sub-envs against single envs, the thread split of
large batches against one call, and the compiled episode sampling against a numpy version. They must agree to
1e-12 (in fact bit for bit). Nothing here is timed.
"""

import math

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv, dynamics, integrators
from softpvtol_gym import model as MK
from softpvtol_gym._parallel import row_ranges
from softpvtol_gym.control import PassivityController, storage_function
from softpvtol_gym.envs.config import EnvConfig
from softpvtol_gym.envs.episodes import N_UNIFORMS, sample_episodes
from softpvtol_gym.params import PARAM_FIELDS
from softpvtol_gym.references import N_REF_PARAMS
from softpvtol_gym.tasks import BUILTIN_TASKS, HOVER_SETPOINT, PAPER_Q0

P = SoftPVTOLParams()
TOL = dict(rtol=1e-12, atol=1e-12)


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
