"""Everything of the SoftPVTOL env that is not physics, written once as batched functions.

The single env (:class:`~softpvtol_gym.envs.soft_pvtol.SoftPVTOLEnv`) and the vector env
(:class:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv`) both drive :class:`BatchSim`, which keeps the
state of N environments as (N, ...) arrays and advances them with the compiled step kernel below; the
single env is the case N = 1. The physics (input maps, RK4, energies) and the controller pieces
(allocation, storage function) are the compiled kernels of :mod:`softpvtol_gym._kernels` and
:mod:`softpvtol_gym.control._kernels`, called per entry; nothing physical is written here.

Contents:
    * :class:`EnvConfig` — frozen, validated configuration (all scales and tier numbers resolved).
    * :func:`reference` — task reference (q_ref, qdot_ref, qddot_ref) at times t, batched.
    * :func:`sample_episodes` — initial states, setpoints/reference parameters, plant parameters and
      per-episode noise keys from a block of uniforms drawn from each env's own RNG.
    * the step kernel (action scaling, allocation, saturation, actuator lag, wind, RK4, observation
      with noise, reward terms, termination), :func:`observe` for resets.
    * counter-based Gaussian noise (per-episode key, step counter, stream) so that noise does not
      depend on how many envs are stepped together.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numba import njit, prange

from .. import _kernels as MK
from ..control import _kernels as CK
from ..control.passivity import PassivityGains
from ..control.references import paper_reference
from ..params import PARAM_FIELDS, SoftPVTOLParams

# ------------------------------------------------------------------------------------ constants
ACTION_MODES = ("actuators", "virtual", "residual")
TASKS = ("hover", "setpoint", "track_paper", "track_random")
TIERS = ("nominal", "mismatch", "wind", "noisy", "hard")
INPUT_MAPS = ("paper", "exact")
ALLOCATIONS = ("paper", "exact", "ideal")
RESIDUAL_SPACES = ("virtual", "actuators")
RENDER_MODES = (None, "rgb_array", "human")

#: kernel codes of the applied-command path
MODE_ACT, MODE_VIRTUAL, MODE_IDEAL, MODE_RES_ACT = 0, 1, 2, 3

PHYSICS_DT = 0.01  # s, the paper's RK4 step
EPISODE_SECONDS = {"hover": 10.0, "setpoint": 10.0, "track_paper": 40.0, "track_random": 20.0}
HOVER_SETPOINT = (0.0, 2.0, 0.0)
PAPER_Q0 = (5.0, 0.0, 0.2 * math.pi, 0.01 * math.pi, -0.15 * math.pi)

GROUND_Z = -1.0  # m: terminate when z < GROUND_Z
BOX_X = 20.0  # m: terminate when |x| > BOX_X
BOX_Z = 20.0  # m: terminate when z > BOX_Z
MAX_LIN_SPEED = 50.0  # m/s: terminate when |xdot| or |zdot| exceeds it
MAX_ANG_SPEED = 100.0  # rad/s: terminate when |thetadot|, |q_l dot| or |q_r dot| exceeds it
OBS_CLIP = 1.0e6

OBS_DIM = 18
OBS_NAMES = (
    "x - x_ref", "z - z_ref", "theta - theta_ref", "sin theta", "cos theta", "q_l", "q_r",
    "xdot", "zdot", "thetadot", "q_l dot", "q_r dot",
    "xdot_ref", "zdot_ref", "thetadot_ref", "xddot_ref", "zddot_ref", "thetaddot_ref",
)

REWARD_TERMS = ("alive", "position", "attitude", "velocity", "effort", "curvature", "crash")
W_POS, POS_SCALE = 0.5, 2.0  # -0.5 min(|e_xz| / 2 m, 1)
W_ATT = 0.1  # -0.1 min(|e_theta| / pi, 1)
W_VEL, VEL_SCALE = 0.1, 5.0  # -0.1 min(|e_v| / 5, 1)
W_EFFORT = 0.1  # -0.1 min(mean(a_n^2), 1)
W_CURV = 0.2  # -0.2 clip((max|q_arm| - pi/2) / (pi/2), 0, 1)^2
CRASH_PENALTY = 10.0

REASONS = ("", "curvature_limit", "ground", "out_of_bounds", "non_finite")
R_NONE, R_CURV, R_GROUND, R_OOB, R_NONFINITE = range(5)

#: fixed number of uniforms each env draws from its RNG at every reset
N_UNIFORMS = 48

# observation-noise std of the measured state (noisy/hard tiers), per q and qdot entry
OBS_NOISE_Q = (0.02, 0.02, 0.01, 0.02, 0.02)  # m, m, rad, rad, rad
OBS_NOISE_QD = (0.05, 0.05, 0.02, 0.05, 0.05)  # m/s, m/s, rad/s, rad/s, rad/s

DEFAULT_TIER_OPTIONS = {
    "mismatch_scale": 0.2,  # plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(1 - s, 1 + s)
    "wind_std": 3.0,  # N, stationary std of the OU force on x and z
    "wind_correlation_time": 1.0,  # s
    "obs_noise_scale": 1.0,  # multiplies OBS_NOISE_Q / OBS_NOISE_QD
    "actuator_time_constant": 0.05,  # s, first-order lag of the applied command
}
TIER_ENABLES = {
    "nominal": (),
    "mismatch": ("mismatch",),
    "wind": ("wind",),
    "noisy": ("noise", "lag"),
    "hard": ("mismatch", "wind", "noise", "lag"),
}
_TIER_OPTION_OF = {
    "mismatch_scale": "mismatch", "wind_std": "wind", "wind_correlation_time": "wind",
    "obs_noise_scale": "noise", "actuator_time_constant": "lag",
}

# cf (float config vector) layout for the kernel
CF_DT, CF_FS, CF_TMAX, CF_TAUMAX, CF_LAG_A, CF_WIND_A, CF_WIND_B, CF_WIND_STD = range(8)
CF_NQ = 8  # 5 entries
CF_NQD = 13  # 5 entries
CF_SCALE = 18  # 5 virtual scales
CF_OFFSET = 23  # 5 virtual offsets
CF_RES_ACT = 28  # 4 actuator residual scales
CF_THOVER = 32
CF_FLAGS = 33  # lag on, wind on, noise on
CF_LEN = 36

# columns of the per-entry diagnostics
D_ALLOC_RES, D_THRUST_SAT, D_TORQUE_SAT, D_ENERGY, D_STORAGE, D_CURV_VIOL, D_ARM_L, D_ARM_R = range(8)
N_DIAG = 8


def _choice(name: str, value: Any, valid: tuple) -> Any:
    if not any(value is v or (isinstance(value, str) and value == v) for v in valid):
        raise ValueError(f"{name} must be one of {list(valid)}, got {value!r}")
    return value


def _positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r} of type {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Validated configuration shared by the single env, the vector env and :class:`PassivityPolicy`.

    See :class:`~softpvtol_gym.envs.soft_pvtol.SoftPVTOLEnv` for the meaning of every argument.
    """

    action_mode: str = "actuators"
    task: str = "hover"
    tier: str = "nominal"
    params: SoftPVTOLParams = dataclasses.field(default_factory=SoftPVTOLParams)
    input_map: str = "paper"
    allocation: str | None = None
    residual_space: str = "virtual"
    frame_skip: int = 1
    max_episode_seconds: float | None = None
    tier_options: dict | None = None
    residual_scale: float = 0.2
    actuator_limits: tuple | None = None

    def __post_init__(self) -> None:
        if self.actuator_limits is not None:
            lim = self.actuator_limits
            if not isinstance(lim, (tuple, list)) or len(lim) != 2:
                raise ValueError(f"actuator_limits must be (thrust_max [N], arm_torque_max [N m]), got {lim!r}")
            _positive_number("actuator_limits[0] (thrust_max)", lim[0])
            _positive_number("actuator_limits[1] (arm_torque_max)", lim[1])
        _choice("action_mode", self.action_mode, ACTION_MODES)
        _choice("task", self.task, TASKS)
        _choice("tier", self.tier, TIERS)
        _choice("input_map", self.input_map, INPUT_MAPS)
        if not isinstance(self.params, SoftPVTOLParams):
            raise ValueError(f"params must be a SoftPVTOLParams, got {self.params!r} of type {type(self.params).__name__}")
        if self.allocation is not None:
            _choice("allocation", self.allocation, ALLOCATIONS)
            if self.allocation == "ideal" and self.action_mode != "virtual":
                raise ValueError(
                    f"allocation='ideal' (tau applied directly) is only valid with action_mode='virtual', "
                    f"got action_mode={self.action_mode!r}; use one of ['exact', 'paper']"
                )
        _choice("residual_space", self.residual_space, RESIDUAL_SPACES)
        if isinstance(self.frame_skip, bool) or not isinstance(self.frame_skip, (int, np.integer)) or self.frame_skip < 1:
            raise ValueError(f"frame_skip must be an int >= 1, got {self.frame_skip!r}")
        if self.max_episode_seconds is not None:
            _positive_number("max_episode_seconds", self.max_episode_seconds)
        _positive_number("residual_scale", self.residual_scale)
        if self.tier_options is not None:
            if not isinstance(self.tier_options, dict):
                raise ValueError(f"tier_options must be a dict, got {self.tier_options!r}")
            for k, v in self.tier_options.items():
                if k not in DEFAULT_TIER_OPTIONS:
                    raise ValueError(f"unknown tier option {k!r}; valid ones are {sorted(DEFAULT_TIER_OPTIONS)}")
                _positive_number(f"tier_options[{k!r}]", v, allow_zero=k != "wind_correlation_time")

    # ---------------------------------------------------------------------------- derived values
    @property
    def resolved_allocation(self) -> str:
        """The allocation actually used: the argument, or "exact" by default."""
        return "exact" if self.allocation is None else self.allocation

    @property
    def controller_loop(self) -> str:
        """PassivityController loop of the residual base controller and of PassivityPolicy."""
        a = self.resolved_allocation
        return {"exact": "exact", "paper": "paper", "ideal": "ideal"}[a]

    @property
    def dt(self) -> float:
        """Control period [s] = 0.01 s x frame_skip."""
        return PHYSICS_DT * int(self.frame_skip)

    @property
    def episode_seconds(self) -> float:
        return EPISODE_SECONDS[self.task] if self.max_episode_seconds is None else float(self.max_episode_seconds)

    @property
    def max_steps(self) -> int:
        return max(1, int(round(self.episode_seconds / self.dt)))

    @property
    def tier_values(self) -> dict:
        """Tier numbers in effect: options of disabled effects are reported as 0 (off)."""
        on = TIER_ENABLES[self.tier]
        vals = dict(DEFAULT_TIER_OPTIONS)
        # an option given by hand switches its effect on with that value
        given = dict(self.tier_options or {})
        vals.update(given)
        enabled = set(on) | {_TIER_OPTION_OF[k] for k in given}
        out = {}
        for k, v in vals.items():
            eff = _TIER_OPTION_OF[k]
            out[k] = v if eff in enabled else (0.0 if k != "wind_correlation_time" else v)
        return out

    @property
    def thrust_max(self) -> float:
        """T_max = 3 x the nominal hover thrust per rotor [N] (102.9 N with defaults)."""
        if self.actuator_limits is not None:
            return float(self.actuator_limits[0])
        return 3.0 * self.params.hover_thrust

    @property
    def arm_torque_max(self) -> float:
        """tau_max = 4 x the larger nominal arm gravity load [N m] (9.8 N m with defaults)."""
        if self.actuator_limits is not None:
            return float(self.actuator_limits[1])
        return 4.0 * max(self.params.arm_gravity_torques)

    @property
    def virtual_scale(self) -> np.ndarray:
        """Per-unit scales of the virtual action: (2 M g, 2 M g, 20 N m, tau_max, tau_max)."""
        w = 2.0 * self.params.total_mass * self.params.g if self.params.g > 0 else 2.0 * self.params.total_mass * 9.8
        return np.array([w, w, 20.0, self.arm_torque_max, self.arm_torque_max])

    @property
    def virtual_offset(self) -> np.ndarray:
        """Virtual force at action 0: (0, M g, 0, 0, 0) (the nominal weight)."""
        return np.array([0.0, self.params.total_mass * self.params.g, 0.0, 0.0, 0.0])

    @property
    def residual_tau_scale(self) -> np.ndarray:
        return self.residual_scale * self.virtual_scale

    @property
    def residual_actuator_scale(self) -> np.ndarray:
        t, a = self.thrust_max, self.arm_torque_max
        return self.residual_scale * np.array([0.5 * t, 0.5 * t, a, a])

    @property
    def kernel_mode(self) -> int:
        if self.action_mode == "actuators":
            return MODE_ACT
        if self.action_mode == "virtual":
            return MODE_IDEAL if self.resolved_allocation == "ideal" else MODE_VIRTUAL
        return MODE_RES_ACT

    @property
    def action_dim(self) -> int:
        if self.action_mode == "virtual" or (self.action_mode == "residual" and self.residual_space == "virtual"):
            return 5
        return 4

    def float_vector(self) -> np.ndarray:
        tv = self.tier_values
        cf = np.zeros(CF_LEN)
        dt = self.dt
        cf[CF_DT] = PHYSICS_DT
        cf[CF_FS] = self.frame_skip
        cf[CF_TMAX] = self.thrust_max
        cf[CF_TAUMAX] = self.arm_torque_max
        tc = tv["actuator_time_constant"]
        cf[CF_LAG_A] = 1.0 - math.exp(-dt / tc) if tc > 0 else 1.0
        a = math.exp(-dt / tv["wind_correlation_time"])
        cf[CF_WIND_A] = a
        cf[CF_WIND_B] = tv["wind_std"] * math.sqrt(1.0 - a * a)
        cf[CF_WIND_STD] = tv["wind_std"]
        s = tv["obs_noise_scale"]
        cf[CF_NQ:CF_NQ + 5] = np.asarray(OBS_NOISE_Q) * s
        cf[CF_NQD:CF_NQD + 5] = np.asarray(OBS_NOISE_QD) * s
        cf[CF_SCALE:CF_SCALE + 5] = self.virtual_scale
        cf[CF_OFFSET:CF_OFFSET + 5] = self.virtual_offset
        cf[CF_RES_ACT:CF_RES_ACT + 4] = self.residual_actuator_scale
        cf[CF_THOVER] = self.params.hover_thrust
        cf[CF_FLAGS] = 1.0 if tc > 0 else 0.0
        cf[CF_FLAGS + 1] = 1.0 if tv["wind_std"] > 0 else 0.0
        cf[CF_FLAGS + 2] = 1.0 if s > 0 else 0.0
        return cf


# ------------------------------------------------------------------------------------ references
N_REF_PARAMS = 21  # setpoint (3) | track_random: 3 sinusoids x (A, w, phi) for x and for z, z0, spare


def reference(task: str, t: np.ndarray, refp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q_ref, qdot_ref, qddot_ref), each (N, 5) with arm entries 0, at times t (N,).

    hover/setpoint: constant (refp[:, 0:3] = x, z, theta); track_paper: :func:`paper_reference`;
    track_random: x = sum_k A_k (sin(w_k t + phi_k) - sin phi_k), z = z0 + the same with other
    (A, w, phi), theta = 0, with analytic derivatives.
    """
    n = t.shape[0]
    if task in ("hover", "setpoint"):
        q = np.zeros((n, 5))
        q[:, :3] = refp[:, :3]
        z = np.zeros((n, 5))
        return q, z, z.copy()
    if task == "track_paper":
        return paper_reference(t)
    q = np.zeros((n, 5))
    qd = np.zeros((n, 5))
    qdd = np.zeros((n, 5))
    for axis in range(2):
        b = 3 + 9 * axis
        A, w, ph = refp[:, b:b + 3], refp[:, b + 3:b + 6], refp[:, b + 6:b + 9]
        arg = w * t[:, None] + ph
        s, c = np.sin(arg), np.cos(arg)
        q[:, axis] = (A * (s - np.sin(ph))).sum(axis=1)
        qd[:, axis] = (A * w * c).sum(axis=1)
        qdd[:, axis] = -(A * w * w * s).sum(axis=1)
    q[:, 1] += refp[:, 0 + 1]  # z0 stored in refp[:, 1]
    return q, qd, qdd


# -------------------------------------------------------------------------------- episode sampling
def sample_episodes(cfg: EnvConfig, u: np.ndarray) -> dict[str, np.ndarray]:
    """Initial state, reference parameters, plant parameters and noise key of len(u) new episodes.

    ``u`` (N, N_UNIFORMS) are uniforms in [0, 1) drawn from each env's own RNG (one ``random`` call
    per reset), so that an env's episode depends only on its own generator. Layout of u: 0-9 initial
    state, 10-12 setpoint, 13-30 track_random reference, 31-38 plant mismatch, 46-47 noise key.
    """
    n = u.shape[0]
    c = 2.0 * u - 1.0  # in [-1, 1)
    refp = np.zeros((n, N_REF_PARAMS))
    q0 = np.zeros((n, 5))
    qd0 = np.zeros((n, 5))
    # perturbation used by hover / setpoint / track_random
    dq = np.stack([c[:, 0], c[:, 1], 0.3 * c[:, 2], 0.3 * c[:, 3], 0.3 * c[:, 4]], axis=1)
    dqd = np.stack([0.5 * c[:, 5], 0.5 * c[:, 6], 0.2 * c[:, 7], 0.2 * c[:, 8], 0.2 * c[:, 9]], axis=1)
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
        r0, rd0, _ = reference(task, np.zeros(n), refp)
        q0 = r0 + 0.5 * dq
        qd0 = rd0 + 0.5 * dqd
    P = np.repeat(cfg.params.array[None, :], n, axis=0)
    s = cfg.tier_values["mismatch_scale"]
    if s > 0:
        idx = [PARAM_FIELDS.index(f) for f in ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")]
        P[:, idx] *= 1.0 + s * c[:, 31:39]
    key = (u[:, 46] * 2.0**53).astype(np.uint64) ^ ((u[:, 47] * 2.0**53).astype(np.uint64) << np.uint64(11))
    return dict(q0=q0, qd0=qd0, refp=refp, P=np.ascontiguousarray(P), key=key)


# --------------------------------------------------------------------------- counter-based noise
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLD = np.uint64(0x9E3779B97F4A7C15)
_N_STREAMS = np.uint64(16)

_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")


@_jit
def _mix(z):
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@_jit
def counter_normal(key, counter, stream):
    """Standard normal from (per-episode key, step counter, stream): splitmix64 hash + Box-Muller."""
    base = _mix(key ^ _mix(np.uint64(counter) * _N_STREAMS + np.uint64(stream) + _GOLD))
    h2 = _mix(base + _GOLD)
    u1 = (np.float64(base >> np.uint64(11)) + 1.0) * (1.0 / 9007199254740992.0)
    u2 = np.float64(h2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


# ----------------------------------------------------------------------------------- observation
@_jit
def _wrap(a):
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@_jit
def _observe_one(q, qd, qr, qdr, qddr, cf, key, counter, obs, qm, qdm):
    """Measured state (noisy tiers: + Gaussian noise) into qm/qdm and the observation into obs."""
    if cf[CF_FLAGS + 2] > 0.0:
        for i in range(5):
            qm[i] = q[i] + cf[CF_NQ + i] * counter_normal(key, counter, i)
            qdm[i] = qd[i] + cf[CF_NQD + i] * counter_normal(key, counter, 5 + i)
    else:
        for i in range(5):
            qm[i] = q[i]
            qdm[i] = qd[i]
    vals = (
        qm[0] - qr[0], qm[1] - qr[1], _wrap(qm[2] - qr[2]), math.sin(qm[2]), math.cos(qm[2]), qm[3], qm[4],
        qdm[0], qdm[1], qdm[2], qdm[3], qdm[4], qdr[0], qdr[1], qdr[2], qddr[0], qddr[1], qddr[2],
    )
    for i in range(OBS_DIM):
        v = vals[i]
        obs[i] = min(max(v, -OBS_CLIP), OBS_CLIP)


@_jit
def _diag_state(q, qd, qr, qdr, P, Pnom, lam, kg, diag):
    diag[D_ENERGY] = MK.kinetic_energy(q, qd, P) + MK.potential_energy(q, P)
    qr2 = np.zeros(5)
    qdr2 = np.zeros(5)
    for i in range(3):
        qr2[i] = qr[i]
        qdr2[i] = qdr[i]
    diag[D_STORAGE] = CK.storage_into(q, qd, qr2, qdr2, Pnom, lam, kg)
    diag[D_CURV_VIOL] = max(abs(q[3]) - math.pi, abs(q[4]) - math.pi, 0.0)


@njit(cache=True)
def observe(q, qd, qr, qdr, qddr, cf, key, counter, P, Pnom, lam, kg, obs, qm, qdm, diag):
    """Observation (and measured state, diagnostics) of entries right after a reset (batched)."""
    for n in range(q.shape[0]):
        _observe_one(q[n], qd[n], qr[n], qdr[n], qddr[n], cf, key[n], counter[n], obs[n], qm[n], qdm[n])
        _diag_state(q[n], qd[n], qr[n], qdr[n], P[n], Pnom, lam, kg, diag[n])


# ------------------------------------------------------------------------------------ step kernel
@_jit
def _step_one(mode, alloc, imap, u, cmd, q, qd, P, cf, lag, lag_init, wind, key, counter,
              qr, qdr, qddr, Pnom, lam, kg, obs, qm, qdm, rew, terms, diag, applied):
    tmax = cf[CF_TMAX]
    taumax = cf[CF_TAUMAX]
    a = np.zeros(5)  # applied command: actuators (4) or, in ideal mode, tau (5)
    thrust_sat = 0.0
    torque_sat = 0.0
    diag[D_ALLOC_RES] = 0.0
    diag[D_ARM_L] = 0.0
    diag[D_ARM_R] = 0.0
    if mode == MODE_ACT:
        a[0] = tmax * 0.5 * (u[0] + 1.0)
        a[1] = tmax * 0.5 * (u[1] + 1.0)
        a[2] = taumax * u[2]
        a[3] = taumax * u[3]
    elif mode == MODE_RES_ACT:
        for i in range(4):
            a[i] = cmd[i] + cf[CF_RES_ACT + i] * u[i]
    else:
        tau = np.empty(5)
        for i in range(5):
            tau[i] = cf[CF_OFFSET + i] + cf[CF_SCALE + i] * u[i]
        if mode == MODE_IDEAL:
            for i in range(5):
                a[i] = tau[i]
        else:
            out = np.empty(4)
            info = np.empty(CK.N_INFO)
            warm = np.zeros(4)
            if alloc == CK.ALLOC_PAPER:
                CK.allocate_paper_into(tau, q[2], Pnom, warm, False, out, info)
            else:
                CK.allocate_exact_into(tau, q[2], Pnom, imap, warm, False, math.pi, out, info)
            Tl, Tr = out[0], out[1]
            if not (math.isfinite(Tl) and math.isfinite(Tr)):
                Tl, Tr = 0.0, 0.0
                thrust_sat = 1.0
            a[0], a[1] = Tl, Tr
            diag[D_ALLOC_RES] = info[CK.INFO_RESIDUAL] if math.isfinite(info[CK.INFO_RESIDUAL]) else 1.0e300
            diag[D_ARM_L] = out[2]
            diag[D_ARM_R] = out[3]
            a[2], a[3] = tau[3], tau[4]
            if imap == MK.INPUT_MAP_EXACT:  # the arm rows get the requested generalized force
                thr = np.zeros(4)
                thr[0], thr[1] = Tl, Tr
                gf = np.empty(5)
                MK.generalized_forces_into(q, thr, Pnom, imap, gf)
                a[2] -= gf[3]
                a[3] -= gf[4]
    na = 5 if mode == MODE_IDEAL else 4
    if mode != MODE_IDEAL:
        for i in range(2):
            if a[i] < 0.0:
                a[i] = 0.0
                thrust_sat = 1.0
            elif a[i] > tmax:
                a[i] = tmax
                thrust_sat = 1.0
        for i in range(2, 4):
            if a[i] < -taumax:
                a[i] = -taumax
                torque_sat = 1.0
            elif a[i] > taumax:
                a[i] = taumax
                torque_sat = 1.0
    diag[D_THRUST_SAT] = thrust_sat
    diag[D_TORQUE_SAT] = torque_sat
    # first-order actuator lag (starts at the first command of the episode)
    if cf[CF_FLAGS] > 0.0:
        if lag_init[0]:
            for i in range(na):
                lag[i] = a[i]
            lag_init[0] = False
        else:
            al = cf[CF_LAG_A]
            for i in range(na):
                lag[i] = lag[i] + al * (a[i] - lag[i])
        for i in range(na):
            a[i] = lag[i]
    for i in range(5):
        applied[i] = a[i] if i < na else math.nan
    # physics: frame_skip RK4 steps with the command held (B(q) re-evaluated at each step)
    q0 = q.copy()
    qd0 = qd.copy()
    tau = np.empty(5)
    dt = cf[CF_DT]
    wind_on = cf[CF_FLAGS + 1] > 0.0
    for _ in range(int(cf[CF_FS])):
        if mode == MODE_IDEAL:
            for i in range(5):
                tau[i] = a[i]
        else:
            MK.generalized_forces_into(q, a, P, imap, tau)
        if wind_on:
            tau[0] += wind[0]
            tau[1] += wind[1]
        MK.rk4_step_into(q, qd, tau, P, dt, q, qd)
    counter[0] += 1
    if wind_on:
        wa, wb = cf[CF_WIND_A], cf[CF_WIND_B]
        wind[0] = wa * wind[0] + wb * counter_normal(key, counter[0], 10)
        wind[1] = wa * wind[1] + wb * counter_normal(key, counter[0], 11)
    # termination
    finite = True
    for i in range(5):
        if not (math.isfinite(q[i]) and math.isfinite(qd[i])):
            finite = False
    reason = R_NONE
    if not finite:
        reason = R_NONFINITE
        for i in range(5):  # keep the last finite state: observation and info stay finite
            q[i] = q0[i]
            qd[i] = qd0[i]
    elif abs(q[3]) > math.pi or abs(q[4]) > math.pi:
        reason = R_CURV
    elif q[1] < GROUND_Z:
        reason = R_GROUND
    elif (abs(q[0]) > BOX_X or q[1] > BOX_Z or abs(qd[0]) > MAX_LIN_SPEED or abs(qd[1]) > MAX_LIN_SPEED
          or abs(qd[2]) > MAX_ANG_SPEED or abs(qd[3]) > MAX_ANG_SPEED or abs(qd[4]) > MAX_ANG_SPEED):
        reason = R_OOB
    _observe_one(q, qd, qr, qdr, qddr, cf, key, counter[0], obs, qm, qdm)
    _diag_state(q, qd, qr, qdr, P, Pnom, lam, kg, diag)
    # reward terms (true state, not the noisy measurement)
    ex, ez = q[0] - qr[0], q[1] - qr[1]
    eth = _wrap(q[2] - qr[2])
    ev = math.sqrt((qd[0] - qdr[0]) ** 2 + (qd[1] - qdr[1]) ** 2 + (qd[2] - qdr[2]) ** 2)
    if mode == MODE_IDEAL:
        eff = 0.0
        for i in range(5):
            eff += ((a[i] - cf[CF_OFFSET + i]) / cf[CF_SCALE + i]) ** 2
        eff /= 5.0
    else:
        th = cf[CF_THOVER]
        eff = 0.25 * (((a[0] - th) / tmax) ** 2 + ((a[1] - th) / tmax) ** 2
                      + (a[2] / taumax) ** 2 + (a[3] / taumax) ** 2)
    cm = max(abs(q[3]), abs(q[4]))
    cp = min(max((cm - 0.5 * math.pi) / (0.5 * math.pi), 0.0), 1.0)
    terms[0] = 1.0
    terms[1] = -W_POS * min(math.sqrt(ex * ex + ez * ez) / POS_SCALE, 1.0)
    terms[2] = -W_ATT * min(abs(eth) / math.pi, 1.0)
    terms[3] = -W_VEL * min(ev / VEL_SCALE, 1.0)
    terms[4] = -W_EFFORT * min(eff, 1.0)
    terms[5] = -W_CURV * cp * cp
    terms[6] = -CRASH_PENALTY if reason != R_NONE else 0.0
    r = 0.0
    for i in range(7):
        r += terms[i]
    rew[0] = r
    return reason


@njit(cache=True)
def step_serial(mode, alloc, imap, u, cmd, q, qd, P, cf, lag, lag_init, wind, key, counter,
                qr, qdr, qddr, Pnom, lam, kg, obs, qm, qdm, rew, terms, diag, applied, reason):
    for n in range(q.shape[0]):
        reason[n] = _step_one(mode, alloc, imap, u[n], cmd[n], q[n], qd[n], P[n], cf, lag[n], lag_init[n:n + 1],
                              wind[n], key[n], counter[n:n + 1], qr[n], qdr[n], qddr[n], Pnom, lam, kg,
                              obs[n], qm[n], qdm[n], rew[n:n + 1], terms[n], diag[n], applied[n])


@njit(cache=True, parallel=True)
def step_parallel(mode, alloc, imap, u, cmd, q, qd, P, cf, lag, lag_init, wind, key, counter,
                  qr, qdr, qddr, Pnom, lam, kg, obs, qm, qdm, rew, terms, diag, applied, reason):
    for n in prange(q.shape[0]):
        reason[n] = _step_one(mode, alloc, imap, u[n], cmd[n], q[n], qd[n], P[n], cf, lag[n], lag_init[n:n + 1],
                              wind[n], key[n], counter[n:n + 1], qr[n], qdr[n], qddr[n], Pnom, lam, kg,
                              obs[n], qm[n], qdm[n], rew[n:n + 1], terms[n], diag[n], applied[n])


PARALLEL_THRESHOLD = 512


# ----------------------------------------------------------------------------------- batch state
class BatchSim:
    """State of N envs as arrays and their step/reset, shared by the single and the vector env."""

    def __init__(self, cfg: EnvConfig, n: int):
        from ..control import PassivityController

        self.cfg = cfg
        self.n = n
        self.mode = cfg.kernel_mode
        self.alloc_code = CK.ALLOC_PAPER if cfg.resolved_allocation == "paper" else CK.ALLOC_EXACT
        self.imap = MK.INPUT_MAP_PAPER if cfg.input_map == "paper" else MK.INPUT_MAP_EXACT
        self.cf = cfg.float_vector()
        self.Pnom = np.ascontiguousarray(cfg.params.array.copy())
        gains = PassivityGains()
        self.lam, self.kg = gains.lam_array, gains.k_array
        self.action_dim = cfg.action_dim
        self.max_steps = cfg.max_steps
        self.dt = cfg.dt
        z5 = lambda: np.zeros((n, 5))  # noqa: E731
        self.q, self.qd, self.qm, self.qdm = z5(), z5(), z5(), z5()
        self.qr, self.qdr, self.qddr = z5(), z5(), z5()
        self.lag = z5()
        self.applied = z5()
        self.lag_init = np.ones(n, dtype=np.bool_)
        self.wind = np.zeros((n, 2))
        self.key = np.zeros(n, dtype=np.uint64)
        self.counter = np.zeros(n, dtype=np.int64)
        self.P = np.repeat(self.Pnom[None, :], n, axis=0)
        self.refp = np.zeros((n, N_REF_PARAMS))
        self.obs = np.zeros((n, OBS_DIM), dtype=np.float32)
        self.rew = np.zeros(n)
        self.terms = np.zeros((n, len(REWARD_TERMS)))
        self.diag = np.zeros((n, N_DIAG))
        self.reason = np.zeros(n, dtype=np.int64)
        self.cmd = np.zeros((n, 4))
        self.u = np.zeros((n, self.action_dim))
        self.clipped = np.zeros(n, dtype=bool)
        self.t = np.zeros(n)
        self.steps = np.zeros(n, dtype=np.int64)
        self._kernel = step_parallel if n >= PARALLEL_THRESHOLD else step_serial
        self._const_ref = cfg.task in ("hover", "setpoint")
        self.controller = None
        if cfg.action_mode == "residual":
            self.controller = PassivityController.from_loop(
                cfg.controller_loop, params=cfg.params, input_map=cfg.input_map, dt=cfg.dt
            )

    # -------------------------------------------------------------------------------- reset
    def reset_entries(self, idx: np.ndarray, u: np.ndarray, options: dict | None = None) -> None:
        """Start new episodes in entries ``idx`` from uniforms ``u`` (len(idx), N_UNIFORMS)."""
        ep = sample_episodes(self.cfg, u)
        if options:
            ep = _apply_options(self.cfg, ep, options)
        self.q[idx] = ep["q0"]
        self.qd[idx] = ep["qd0"]
        self.refp[idx] = ep["refp"]
        self.P[idx] = ep["P"]
        self.key[idx] = ep["key"]
        self.counter[idx] = 0
        self.t[idx] = 0.0
        self.steps[idx] = 0
        self.lag[idx] = 0.0
        self.lag_init[idx] = True
        self.applied[idx] = np.nan
        self.clipped[idx] = False
        self.reason[idx] = R_NONE
        self.rew[idx] = 0.0
        self.terms[idx] = 0.0
        qr, qdr, qddr = reference(self.cfg.task, self.t[idx], self.refp[idx])
        self.qr[idx], self.qdr[idx], self.qddr[idx] = qr, qdr, qddr
        # initial wind: stationary OU sample from the counter noise at counter 0
        std = self.cf[CF_WIND_STD]
        if std > 0:
            for j, n in enumerate(np.atleast_1d(idx)):
                self.wind[n, 0] = std * counter_normal(self.key[n], 0, 10)
                self.wind[n, 1] = std * counter_normal(self.key[n], 0, 11)
        else:
            self.wind[idx] = 0.0
        ii = np.atleast_1d(np.arange(self.n)[idx])
        obs = np.empty((ii.size, OBS_DIM), dtype=np.float32)
        qm = np.empty((ii.size, 5))
        qdm = np.empty((ii.size, 5))
        diag = np.zeros((ii.size, N_DIAG))
        observe(self.q[ii], self.qd[ii], self.qr[ii], self.qdr[ii], self.qddr[ii], self.cf, self.key[ii],
                self.counter[ii], self.P[ii], self.Pnom, self.lam, self.kg, obs, qm, qdm, diag)
        self.obs[ii], self.qm[ii], self.qdm[ii], self.diag[ii] = obs, qm, qdm, diag
        if self.controller is not None:
            mask = np.zeros(self.n, dtype=bool)
            mask[ii] = True
            self.controller.reset(mask)

    # --------------------------------------------------------------------------------- step
    def check_action(self, action, batched: bool) -> np.ndarray:
        """Validate (shape, finite) and clip; returns the clipped float64 (N, A) action."""
        expected = (self.n, self.action_dim) if batched else (self.action_dim,)
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"action must be a real array of shape {expected} in [-1, 1], got {action!r}"
            ) from None
        if a.shape != expected:
            raise ValueError(
                f"action must have shape {expected} (action_mode={self.cfg.action_mode!r}), got shape {a.shape}"
            )
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite (in [-1, 1]), got {action!r}")
        a = a.reshape(self.n, self.action_dim)
        np.clip(a, -1.0, 1.0, out=self.u)
        np.not_equal(a, self.u).any(axis=1, out=self.clipped)
        return self.u

    def step(self) -> None:
        """Advance every entry by one control step with the (checked) action in ``self.u``."""
        cfg = self.cfg
        if self.controller is not None:
            if cfg.residual_space == "virtual":
                # an all-zero residual is not added at all, so that action 0 is the controller exactly
                res = self.u * cfg.residual_tau_scale if self.u.any() else None
                out = self.controller(self.qm, self.qdm, self.qr, self.qdr, self.qddr, tau_residual=res)
            else:
                out = self.controller(self.qm, self.qdm, self.qr, self.qdr, self.qddr)
            self.cmd[:] = out.actuators
            alloc_res = out.allocation.residual
            arm_ref = out.arm_reference
        self.steps += 1
        np.multiply(self.steps, self.dt, out=self.t)
        if not self._const_ref:
            self.qr, self.qdr, self.qddr = (np.ascontiguousarray(x) for x in reference(cfg.task, self.t, self.refp))
        self._kernel(self.mode, self.alloc_code, self.imap, self.u, self.cmd, self.q, self.qd, self.P, self.cf,
                     self.lag, self.lag_init, self.wind, self.key, self.counter, self.qr, self.qdr, self.qddr,
                     self.Pnom, self.lam, self.kg, self.obs, self.qm, self.qdm, self.rew, self.terms, self.diag,
                     self.applied, self.reason)
        if self.controller is not None:
            self.diag[:, D_ALLOC_RES] = alloc_res
            self.diag[:, D_ARM_L:D_ARM_R + 1] = arm_ref


def _apply_options(cfg: EnvConfig, ep: dict, options: dict) -> dict:
    """reset(options=...): "q0" (5,), "qdot0" (5,), "setpoint" (3,) (hover/setpoint tasks)."""
    valid = ("q0", "qdot0", "setpoint")
    for k in options:
        if k not in valid:
            raise ValueError(f"unknown reset option {k!r}; valid ones are {list(valid)}")
    for k, key, size in (("q0", "q0", 5), ("qdot0", "qd0", 5), ("setpoint", None, 3)):
        if k not in options or options[k] is None:
            continue
        v = np.asarray(options[k], dtype=np.float64)
        if v.shape != (size,) or not np.isfinite(v).all():
            raise ValueError(f"reset option {k!r} must be {size} finite numbers, got {options[k]!r}")
        if k == "setpoint":
            if cfg.task not in ("hover", "setpoint"):
                raise ValueError(f"reset option 'setpoint' needs task 'hover' or 'setpoint', got {cfg.task!r}")
            ep["refp"][:, :3] = v
        else:
            ep[key][:] = v
    return ep
