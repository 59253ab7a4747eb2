"""A readable reference of the SoftPVTOL-v0 env step in plain numpy.

Written from docs/env.md ("Step, in order", "Observation", "Actions", "Reward", "Episode end",
"Tiers", "Counter-based noise") and docs/model.md (D, C, g, input maps, RK4), not from the env's
compiled kernels: the model is re-written here from the equations in docs/model.md (curvature
functions by their closed forms, Taylor series below |q| = 1 where the closed forms cancel), the
step is one function per documented stage. The only package pieces used are separately verified public
APIs: ``softpvtol_gym.control.allocate`` (virtual mode) and ``PassivityController`` (residual mode's base
controller), ``storage_function`` (the info's storage), and ``SoftPVTOLParams``.

The reference starts an episode from what the env's reset drew (initial state, plant parameters, noise
key, reference parameters: :func:`episode_from_sim`) and then steps on its own.
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction

import numpy as np

from softpvtol_gym import SoftPVTOLParams
from softpvtol_gym.control import PassivityController, allocate, storage_function

PHYSICS_DT = 0.01  # s, one RK4 step
EPISODE_SECONDS = {"hover": 10.0, "setpoint": 10.0, "track_paper": 40.0, "track_random": 20.0}
OBS_CLIP = 1.0e6
REWARD_TERMS = ("alive", "position", "attitude", "velocity", "effort", "curvature", "crash")
OBS_NOISE_Q = np.array([0.02, 0.02, 0.01, 0.02, 0.02])
OBS_NOISE_QD = np.array([0.05, 0.05, 0.02, 0.05, 0.05])
# streams of the counter-based noise (docs/env.md): measured q (0-4), measured qdot (5-9), wind x, z
STREAM_Q, STREAM_QD, STREAM_WIND_X, STREAM_WIND_Z = 0, 5, 10, 11


# ----------------------------------------------------------------------------- counter-based noise
_MASK = (1 << 64) - 1
_M1, _M2, _GOLD = 0xBF58476D1CE4E5B9, 0x94D049BB133111EB, 0x9E3779B97F4A7C15


def splitmix64(z: int) -> int:
    """The splitmix64 finaliser on unsigned 64-bit integers."""
    z = ((z ^ (z >> 30)) * _M1) & _MASK
    z = ((z ^ (z >> 27)) * _M2) & _MASK
    return z ^ (z >> 31)


def counter_normal(key: int, counter: int, stream: int) -> float:
    """Standard normal of (episode key, step counter, stream), docs/env.md "Counter-based noise"."""
    h1 = splitmix64(key ^ splitmix64((counter * 16 + stream + _GOLD) & _MASK))
    h2 = splitmix64((h1 + _GOLD) & _MASK)
    u1 = ((h1 >> 11) + 1.0) * 2.0**-53  # (0, 1]
    u2 = (h2 >> 11) * 2.0**-53  # [0, 1)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


# ------------------------------------------------------------------------- model (docs/model.md)
def _series(coef):
    """Coefficients (as floats) of a power series in s = q^2 given by coef(i), i = 0..13."""
    return [float(coef(i)) for i in range(14)]


def _fact(n: int) -> int:
    return math.factorial(n)


_S0 = _series(lambda i: Fraction((-1) ** i, _fact(2 * i + 1)))  # sin q / q
_C1 = _series(lambda i: Fraction((-1) ** i, _fact(2 * i + 2)))  # (1 - cos q) / q^2
_D1_Q = _series(lambda i: Fraction((-1) ** i * 2 * (i + 1), _fact(2 * i + 3)))  # D1 / q
_D2 = _series(lambda i: Fraction((-1) ** i * (2 * i + 1), _fact(2 * i + 2)))  # D2
_D1P = [c * (2 * i + 1) for i, c in enumerate(_D1_Q)]  # D1' = d(q * D1_Q(q^2))/dq
_D2P_Q = [c * 2 * (i + 1) for i, c in enumerate(_D2[1:])]  # D2' / q


def _poly(c, s):
    r = 0.0
    for a in reversed(c):
        r = r * s + a
    return r


def curvature_functions(q: float) -> tuple[float, float, float, float, float, float]:
    """(S0, C1, D1, D2, D1', D2') of docs/model.md at curvature q: closed forms for |q| >= 1, Taylor
    series in q^2 below (where the closed forms lose digits to cancellation)."""
    if abs(q) < 1.0:
        s = q * q
        return (_poly(_S0, s), _poly(_C1, s), q * _poly(_D1_Q, s), _poly(_D2, s), _poly(_D1P, s),
                q * _poly(_D2P_Q, s))
    sn, cs = math.sin(q), math.cos(q)
    q2, q3 = q * q, q * q * q
    return (sn / q, (1.0 - cs) / q2, (sn - q * cs) / q2, (cs + q * sn - 1.0) / q2,
            (q2 * sn - 2.0 * sn + 2.0 * q * cs) / q3, (q2 * cs - 2.0 * cs - 2.0 * q * sn + 2.0) / q3)


@dataclasses.dataclass(frozen=True)
class Model:
    """D(q), C(q, qdot), g(q), B(q) a and the energy of docs/model.md for one parameter set."""

    p: SoftPVTOLParams

    def terms(self, q, qd):
        p = self.p
        M = p.m + p.m_l + p.m_r
        _, _, d1l, d2l, d1pl, d2pl = curvature_functions(q[3])
        _, _, d1r, d2r, d1pr, d2pr = curvature_functions(q[4])
        kl, kr = p.m_l * p.l_l, p.m_r * p.l_r
        D = np.array([
            [M, 0.0, 0.0, kl * d1l, -kr * d1r],
            [0.0, M, 0.0, kl * d2l, kr * d2r],
            [0.0, 0.0, p.I, 0.0, 0.0],
            [kl * d1l, kl * d2l, 0.0, kl * p.l_l * (d1l * d1l + d2l * d2l) + p.I_l, 0.0],
            [-kr * d1r, kr * d2r, 0.0, 0.0, kr * p.l_r * (d1r * d1r + d2r * d2r) + p.I_r],
        ])
        C = np.zeros((5, 5))
        C[0, 3], C[1, 3] = kl * d1pl * qd[3], kl * d2pl * qd[3]
        C[0, 4], C[1, 4] = -kr * d1pr * qd[4], kr * d2pr * qd[4]
        C[3, 3] = kl * p.l_l * (d1l * d1pl + d2l * d2pl) * qd[3]
        C[4, 4] = kr * p.l_r * (d1r * d1pr + d2r * d2pr) * qd[4]
        g = np.array([0.0, p.g * M, 0.0, p.g * kl * d2l, p.g * kr * d2r])
        return D, C, g

    def mass_matrix(self, q):
        return self.terms(q, np.zeros(5))[0]

    def generalized_forces(self, q, a, input_map: str):
        """B(q) a, a = (T_l, T_r, tau_l, tau_r) (docs/model.md "Input maps")."""
        p = self.p
        th, ql, qr = q[2], q[3], q[4]
        Tl, Tr = a[0], a[1]
        s0l, c1l = curvature_functions(ql)[:2]
        s0r, c1r = curvature_functions(qr)[:2]
        ux = Tl * math.sin(ql) - Tr * math.sin(qr)
        uz = Tl * math.cos(ql) + Tr * math.cos(qr)
        ct, st = math.cos(th), math.sin(th)
        tx, tz = ct * ux - st * uz, st * ux + ct * uz  # R(theta) (ux, uz)
        if input_map == "paper":
            tth = p.l_r * Tr * math.cos(qr) * s0r - p.l_l * Tl * math.cos(ql) * s0l
            return np.array([tx, tz, tth, a[2], a[3]])
        eps = p.epsilon
        tth = Tr * (eps * math.cos(qr) + p.l_r * s0r) - Tl * (eps * math.cos(ql) + p.l_l * s0l)
        return np.array([tx, tz, tth, a[2] + Tl * p.l_l * c1l, a[3] + Tr * p.l_r * c1r])

    def qddot(self, q, qd, tau):
        D, C, g = self.terms(q, qd)
        return np.linalg.solve(D, tau - C @ qd - g)

    def energy(self, q, qd):
        p = self.p
        D = self.mass_matrix(q)
        c1l, c1r = curvature_functions(q[3])[1], curvature_functions(q[4])[1]
        pot = p.g * ((p.m + p.m_l + p.m_r) * q[1] + p.m_l * p.l_l * q[3] * c1l + p.m_r * p.l_r * q[4] * c1r)
        return 0.5 * qd @ D @ qd + pot

    def rk4(self, q, qd, force, dt):
        """Classical RK4 of (q, qdot) over dt; force(q_stage) is the generalized force at each stage."""
        h = 0.5 * dt
        k1 = self.qddot(q, qd, force(q))
        q2, v2 = q + h * qd, qd + h * k1
        k2 = self.qddot(q2, v2, force(q2))
        q3, v3 = q + h * v2, qd + h * k2
        k3 = self.qddot(q3, v3, force(q3))
        q4, v4 = q + dt * v3, qd + dt * k3
        k4 = self.qddot(q4, v4, force(q4))
        return q + dt / 6.0 * (qd + 2.0 * v2 + 2.0 * v3 + v4), qd + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


# -------------------------------------------------------------------------- task references
def reference(task: str, t: float, rp: dict):
    """(q_ref, qdot_ref, qddot_ref) (5 each, arm entries 0) at time t, from the docs/env.md formulas."""
    q, qd, qdd = np.zeros(5), np.zeros(5), np.zeros(5)
    if task in ("hover", "setpoint"):
        q[:3] = rp["setpoint"]
    elif task == "track_paper":  # x = 4 sin(t/2), z = 3 cos(t/10) + 4
        q[0], qd[0], qdd[0] = 4.0 * math.sin(t / 2), 2.0 * math.cos(t / 2), -math.sin(t / 2)
        q[1], qd[1], qdd[1] = 3.0 * math.cos(t / 10) + 4.0, -0.3 * math.sin(t / 10), -0.03 * math.cos(t / 10)
    else:  # track_random: sum_k A_k (sin(w_k t + phi_k) - sin phi_k), z offset z0
        for axis, name in ((0, "x"), (1, "z")):
            A, w, ph = rp[name]
            q[axis] = float(np.sum(A * (np.sin(w * t + ph) - np.sin(ph))))
            qd[axis] = float(np.sum(A * w * np.cos(w * t + ph)))
            qdd[axis] = float(np.sum(-A * w * w * np.sin(w * t + ph)))
        q[1] += rp["z0"]
    return q, qd, qdd


# ---------------------------------------------------------------------------------- episodes
@dataclasses.dataclass
class Episode:
    """What a reset draws: initial state, plant parameters, noise key, reference parameters."""

    q0: np.ndarray
    qd0: np.ndarray
    plant: SoftPVTOLParams
    key: int
    ref: dict


def episode_from_sim(sim, i: int, task: str) -> Episode:
    """The episode sub-env i of the env's BatchSim has just been reset to, read from its public views.

    Reference parameters: hover/setpoint the set-point (the reference at t = 0); track_random the
    per-episode (A_k, w_k, phi_k) of x and of z and z0 from ``sim.refp`` (row layout: z0 at 1, x's
    A, w, phi at 3:6, 6:9, 9:12, z's at 12:15, 15:18, 18:21).
    """
    if task in ("hover", "setpoint"):
        ref = {"setpoint": np.array(sim.qr[i, :3], dtype=np.float64)}
    elif task == "track_random":
        r = np.array(sim.refp[i], dtype=np.float64)
        ref = {"z0": float(r[1]), "x": (r[3:6], r[6:9], r[9:12]), "z": (r[12:15], r[15:18], r[18:21])}
    else:
        ref = {}
    return Episode(q0=np.array(sim.q[i], dtype=np.float64), qd0=np.array(sim.qd[i], dtype=np.float64),
                   plant=SoftPVTOLParams.from_array(np.array(sim.P[i])), key=int(sim.key[i]), ref=ref)


def wrap(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclasses.dataclass
class StepResult:
    obs: np.ndarray  # float64 (the env returns it as float32)
    reward: float
    terms: dict
    terminated: bool
    truncated: bool
    reason: str | None
    info: dict


class ReferenceEnv:
    """One env, stepped in plain numpy from the docs. ``config`` is the env's EnvConfig (its
    constructor arguments are read: action_mode, task, params, input_map, allocation, residual_space,
    residual_scale, frame_skip, max_episode_seconds, actuator_limits, controller_loop; and
    ``tier_values``)."""

    def __init__(self, config):
        c = config
        self.mode, self.task, self.imap = c.action_mode, c.task, c.input_map
        self.allocation = c.allocation if c.allocation is not None else "exact"
        # the residual base controller's loop (docs/env.md): controller_loop, or from the allocation
        # ("paper" -> "paper", otherwise "bounded")
        self.loop = c.controller_loop or ("paper" if self.allocation == "paper" else "bounded")
        self.residual_space = c.residual_space
        self.nominal = c.params
        p = c.params
        M = p.m + p.m_l + p.m_r
        self.hover_thrust = 0.5 * M * p.g
        if c.actuator_limits is not None:
            self.tmax, self.taumax = float(c.actuator_limits[0]), float(c.actuator_limits[1])
        else:  # T_max = 3 x hover thrust, tau_max = 4 x the arm gravity load g m_i l_i / 2
            self.tmax = 3.0 * self.hover_thrust
            self.taumax = 4.0 * max(0.5 * p.g * p.m_l * p.l_l, 0.5 * p.g * p.m_r * p.l_r)
        self.v_offset = np.array([0.0, M * p.g, 0.0, 0.0, 0.0])
        self.v_scale = np.array([2 * M * p.g, 2 * M * p.g, 20.0, self.taumax, self.taumax])
        self.res_tau_scale = c.residual_scale * self.v_scale
        self.res_act_scale = c.residual_scale * np.array([self.tmax / 2, self.tmax / 2, self.taumax, self.taumax])
        self.frame_skip = int(c.frame_skip)
        self.dt = PHYSICS_DT * self.frame_skip
        seconds = EPISODE_SECONDS[c.task] if c.max_episode_seconds is None else float(c.max_episode_seconds)
        self.max_steps = max(1, round(seconds / self.dt))
        tv = c.tier_values
        self.wind_std = tv["wind_std"]
        self.wind_a = math.exp(-self.dt / tv["wind_correlation_time"])
        self.wind_b = self.wind_std * math.sqrt(1.0 - self.wind_a**2)
        tc = tv["actuator_time_constant"]
        self.lag_alpha = 1.0 - math.exp(-self.dt / tc) if tc > 0 else None
        s = tv["obs_noise_scale"]
        self.noise_q, self.noise_qd = s * OBS_NOISE_Q, s * OBS_NOISE_QD
        self.ideal = self.mode == "virtual" and self.allocation == "ideal"
        five = self.mode == "virtual" or (self.mode == "residual" and self.residual_space == "virtual")
        self.action_dim = 5 if five else 4

    # ------------------------------------------------------------------------------ episode
    def start(self, ep: Episode) -> np.ndarray:
        """Start an episode; returns the first observation (float64)."""
        self.ep = ep
        self.plant = Model(ep.plant)
        self.q, self.qd = ep.q0.copy(), ep.qd0.copy()
        self.counter = 0
        self.steps = 0
        self.lag = None  # the lag state starts at the first command
        self.wind = np.zeros(2)
        if self.wind_std > 0:  # stationary OU sample at counter 0
            self.wind = self.wind_std * np.array([counter_normal(ep.key, 0, STREAM_WIND_X),
                                                  counter_normal(ep.key, 0, STREAM_WIND_Z)])
        self.controller = None
        if self.mode == "residual":
            self.controller = PassivityController.from_loop(self.loop, params=self.nominal,
                                                            input_map=self.imap, dt=self.dt)
        self.ref = reference(self.task, 0.0, ep.ref)
        self.obs = self._observe()
        return self.obs

    def start_from_sim(self, sim, i: int = 0) -> np.ndarray:
        return self.start(episode_from_sim(sim, i, self.task))

    # -------------------------------------------------------------------------- observation
    def _measure(self):
        """Measured state: the true state + counter-based Gaussian noise (streams 0-9) if on."""
        qm, qdm = self.q.copy(), self.qd.copy()
        if self.noise_q.any():
            for i in range(5):
                qm[i] += self.noise_q[i] * counter_normal(self.ep.key, self.counter, STREAM_Q + i)
                qdm[i] += self.noise_qd[i] * counter_normal(self.ep.key, self.counter, STREAM_QD + i)
        return qm, qdm

    def _observe(self) -> np.ndarray:
        self.qm, self.qdm = self._measure()
        qm, qdm = self.qm, self.qdm
        qr, qdr, qddr = self.ref
        o = np.empty(18)
        o[0], o[1] = qm[0] - qr[0], qm[1] - qr[1]
        o[2] = wrap(qm[2] - qr[2])
        o[3], o[4] = math.sin(qm[2]), math.cos(qm[2])
        o[5], o[6] = qm[3], qm[4]
        o[7:12] = qdm
        o[12:15] = qdr[:3]
        o[15:18] = qddr[:3]
        return np.clip(o, -OBS_CLIP, OBS_CLIP)

    # ---------------------------------------------------------------------------- command
    def _command(self, u, measured=None):
        """The command (actuators (4), or tau (5) in ideal mode) before saturation and lag; info."""
        info = {"allocation_residual": 0.0, "thrust_saturated": False}
        if self.mode == "actuators":
            return np.array([self.tmax * (u[0] + 1) / 2, self.tmax * (u[1] + 1) / 2,
                             self.taumax * u[2], self.taumax * u[3]]), info
        if self.mode == "virtual":
            tau = self.v_offset + self.v_scale * u
            if self.ideal:
                return tau, info
            # allocation at the plant's state with the nominal params; arm rows = generalized arm forces
            out, ainfo = allocate(tau, self.q, self.nominal, self.allocation, input_map=self.imap,
                                  return_info=True)
            Tl, Tr = float(out[0]), float(out[1])
            arms = tau[3:5].copy()
            if self.imap == "exact":  # compensate the thrusts' own work on the curvatures
                arms -= Model(self.nominal).generalized_forces(self.q, (Tl, Tr, 0.0, 0.0), "exact")[3:5]
            info["allocation_residual"] = float(ainfo.residual)
            return np.array([Tl, Tr, arms[0], arms[1]]), info
        # residual: the passivity controller fed with the last observation's measured state and reference
        qr, qdr, qddr = self.ref
        res = self.res_tau_scale * u if self.residual_space == "virtual" else None
        qm, qdm = (self.qm, self.qdm) if measured is None else measured
        out = self.controller(np.array(qm, dtype=np.float64), np.array(qdm, dtype=np.float64), qr, qdr, qddr,
                              tau_residual=res)
        cmd = np.array(out.actuators, dtype=np.float64)
        if self.residual_space == "actuators":
            cmd = cmd + self.res_act_scale * u
        info["allocation_residual"] = float(out.allocation.residual)
        return cmd, info

    def _saturate(self, cmd):
        if self.ideal:
            return cmd, False, False
        T = np.clip(cmd[:2], 0.0, self.tmax)
        A = np.clip(cmd[2:4], -self.taumax, self.taumax)
        return np.concatenate([T, A]), bool((T != cmd[:2]).any()), bool((A != cmd[2:4]).any())

    # ------------------------------------------------------------------------------- step
    def step(self, action, measured=None) -> StepResult:
        """One control step. ``measured`` = (q_m, qdot_m), if given, replaces the reference's own
        measured state as the residual controller's input (see tests/envs/test_reference.py: the paper
        allocation's Newton stopping rule makes its output jump by ~1e-10 under 1e-16 input changes)."""
        a = np.asarray(action, dtype=np.float64).reshape(self.action_dim)
        u = np.clip(a, -1.0, 1.0)
        clipped = bool((u != a).any())
        cmd, info = self._command(u, measured)
        cmd, tsat, asat = self._saturate(cmd)
        info["thrust_saturated"] = info["thrust_saturated"] or tsat
        info["arm_torque_saturated"] = asat
        if self.lag_alpha is not None:  # first-order lag, initialised to the first command
            self.lag = cmd.copy() if self.lag is None else self.lag + self.lag_alpha * (cmd - self.lag)
            cmd = self.lag.copy()
        self.applied = cmd
        # zero-order hold: actuators (tau in ideal mode) and the wind held over frame_skip RK4 steps
        ext = np.array([self.wind[0], self.wind[1], 0.0, 0.0, 0.0])
        if self.ideal:
            def force(qs):
                return cmd + ext
        else:
            def force(qs):
                return self.plant.generalized_forces(qs, cmd, self.imap) + ext
        q, qd = self.q, self.qd
        with np.errstate(all="ignore"):
            for _ in range(self.frame_skip):
                try:
                    q, qd = self.plant.rk4(q, qd, force, PHYSICS_DT)
                except np.linalg.LinAlgError:
                    q, qd = np.full(5, np.nan), np.full(5, np.nan)
        self.steps += 1
        self.counter += 1
        if self.wind_std > 0:  # OU update after the step
            self.wind = self.wind_a * self.wind + self.wind_b * np.array(
                [counter_normal(self.ep.key, self.counter, STREAM_WIND_X),
                 counter_normal(self.ep.key, self.counter, STREAM_WIND_Z)])
        reason = None
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            reason = "non_finite"  # the last finite state stays
        else:
            self.q, self.qd = q, qd
            if abs(q[3]) > math.pi or abs(q[4]) > math.pi:
                reason = "curvature_limit"
            elif q[1] < -1.0:
                reason = "ground"
            elif (abs(q[0]) > 20.0 or q[1] > 20.0 or abs(qd[0]) > 50.0 or abs(qd[1]) > 50.0
                  or max(abs(qd[2]), abs(qd[3]), abs(qd[4])) > 100.0):
                reason = "out_of_bounds"
        t = self.steps * self.dt
        self.ref = reference(self.task, t, self.ep.ref)
        self.obs = self._observe()
        terms = self._reward_terms(reason is not None)
        reward = sum(terms.values())
        truncated = reason is None and self.steps >= self.max_steps
        qr, qdr = self.ref[0], self.ref[1]
        info.update(
            action_clipped=clipped, time=t,
            total_energy=self.plant.energy(self.q, self.qd),
            storage_function=float(storage_function(self.q, self.qd, np.r_[qr[:3], 0.0, 0.0],
                                                    np.r_[qdr[:3], 0.0, 0.0], self.nominal)),
            curvature_violation=max(abs(self.q[3]) - math.pi, abs(self.q[4]) - math.pi, 0.0),
        )
        return StepResult(self.obs, reward, terms, reason is not None, truncated,
                          reason if reason is not None else ("time_limit" if truncated else None), info)

    # ----------------------------------------------------------------------------- reward
    def _reward_terms(self, crashed: bool) -> dict:
        """The docs/env.md reward table at the true state and the reference at the step's end."""
        q, qd = self.q, self.qd
        qr, qdr, _ = self.ref
        e = math.hypot(q[0] - qr[0], q[1] - qr[1])
        eth = wrap(q[2] - qr[2])
        ev = float(np.linalg.norm(qd[:3] - qdr[:3]))
        a = self.applied
        if self.ideal:
            an = (a - self.v_offset) / self.v_scale
        else:
            th = self.hover_thrust
            an = np.array([(a[0] - th) / self.tmax, (a[1] - th) / self.tmax, a[2] / self.taumax, a[3] / self.taumax])
        cm = max(abs(q[3]), abs(q[4]))
        cp = min(max((cm - math.pi / 2) / (math.pi / 2), 0.0), 1.0)
        return {
            "alive": 1.0,
            "position": -0.5 * min(e / 2.0, 1.0),
            "attitude": -0.1 * min(abs(eth) / math.pi, 1.0),
            "velocity": -0.1 * min(ev / 5.0, 1.0),
            "effort": -0.1 * min(float(np.mean(an**2)), 1.0),
            "curvature": -0.2 * cp * cp,
            "crash": -10.0 if crashed else 0.0,
        }
