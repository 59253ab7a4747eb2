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
      with noise, reward terms, termination), :func:`reset_rows` for resets. The state of the N envs is
      a few packed arrays (``F_*``, ``I_*`` column blocks), the physics of 64 envs at a time runs as
      SIMD lanes (``_kernels.rk4_lanes``), the residual mode's base controller is the fused controller
      step of :mod:`softpvtol_gym.control._kernels`, and large batches are split over threads
      (:mod:`softpvtol_gym._parallel`). Speed: ``benchmarks/``.
    * counter-based Gaussian noise (per-episode key, step counter, stream) so that noise does not
      depend on how many envs are stepped together.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from numba import njit

from .. import _kernels as MK
from ..control import _kernels as CK
from .._batching import check_curvature
from .._parallel import MIN_ROWS, row_ranges, run_split
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

    @functools.cached_property
    def mismatch_scale(self) -> float:
        """Plant parameter mismatch scale in effect (0: off); cached (the config is immutable)."""
        return self.tier_values["mismatch_scale"]

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
        # actuator-space residuals only: a virtual residual enters through the controller's tau alone
        # (before 2026-11-23 its first 4 entries were also added to the actuators: applied twice)
        if self.action_mode == "residual" and self.residual_space == "actuators":
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
    With c = 2 u - 1 in [-1, 1): the perturbation of hover / setpoint / track_random is
    dq = (c0, c1, 0.3 c2, 0.3 c3, 0.3 c4), dqd = (0.5 c5, 0.5 c6, 0.2 c7, 0.2 c8, 0.2 c9); hover starts
    at the setpoint + dq, setpoint at x = 3 c0, z = 2 + 2 c1 (setpoint x = 3 c10, z = 2 + 2 c11,
    theta = 0.3 c12), track_paper at the paper's q0 at rest, track_random at its reference + dq/2 (the
    reference: z0 = 3, amplitudes u*(1.0 | 0.5), rates 0.2 + 0.6 u, phases 2 pi u); plant mismatch
    scales the masses, inertias and lengths by 1 + s c31..c38. (Compiled: :func:`_sample_rows`.)
    """
    n = u.shape[0]
    refp = np.empty((n, N_REF_PARAMS))
    q0 = np.empty((n, 5))
    qd0 = np.empty((n, 5))
    P = np.empty((n, len(PARAM_FIELDS)))
    key = np.empty(n, dtype=np.uint64)
    _sample_rows(np.ascontiguousarray(u, dtype=np.float64), TASKS.index(cfg.task), cfg.params.array,
                 float(cfg.mismatch_scale), refp, q0, qd0, P, key)
    if cfg.task == "track_random":
        r0, rd0, _ = reference(cfg.task, np.zeros(n), refp)
        q0 = r0 + q0  # q0, qd0 hold dq / 2, dqd / 2 here
        qd0 = rd0 + qd0
    return dict(q0=q0, qd0=qd0, refp=refp, P=P, key=key)


_MISMATCH_COLUMNS = tuple(PARAM_FIELDS.index(f) for f in ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r"))


@njit(cache=True, nogil=True, error_model="numpy")
def _sample_rows(u, task, params, scale, refp, q0, qd0, P, key):
    """The rows of :func:`sample_episodes` (task: index into TASKS; track_random: q0, qd0 get the
    halved perturbation, the caller adds the reference)."""
    two_pi = 2.0 * math.pi
    for i in range(u.shape[0]):
        c0, c1, c2, c3, c4 = (2.0 * u[i, 0] - 1.0, 2.0 * u[i, 1] - 1.0, 2.0 * u[i, 2] - 1.0, 2.0 * u[i, 3] - 1.0,
                              2.0 * u[i, 4] - 1.0)
        c5, c6, c7, c8, c9 = (2.0 * u[i, 5] - 1.0, 2.0 * u[i, 6] - 1.0, 2.0 * u[i, 7] - 1.0, 2.0 * u[i, 8] - 1.0,
                              2.0 * u[i, 9] - 1.0)
        dq = (c0 * 1.0, c1 * 1.0, c2 * 0.3, c3 * 0.3, c4 * 0.3)
        dqd = (c5 * 0.5, c6 * 0.5, c7 * 0.2, c8 * 0.2, c9 * 0.2)
        for k in range(N_REF_PARAMS):
            refp[i, k] = 0.0
        for k in range(5):
            q0[i, k] = 0.0
            qd0[i, k] = dqd[k]
        if task == 0:  # hover
            for k in range(3):
                refp[i, k] = HOVER_SETPOINT[k]
                q0[i, k] = HOVER_SETPOINT[k]
            for k in range(5):
                q0[i, k] = q0[i, k] + dq[k]
        elif task == 1:  # setpoint
            refp[i, 0] = 3.0 * (2.0 * u[i, 10] - 1.0)
            refp[i, 1] = 2.0 + 2.0 * (2.0 * u[i, 11] - 1.0)
            refp[i, 2] = 0.3 * (2.0 * u[i, 12] - 1.0)
            q0[i, 0] = 3.0 * c0
            q0[i, 1] = 2.0 + 2.0 * c1
            q0[i, 2], q0[i, 3], q0[i, 4] = dq[2], dq[3], dq[4]
        elif task == 2:  # track_paper
            for k in range(5):
                q0[i, k] = PAPER_Q0[k]
                qd0[i, k] = 0.0
        else:  # track_random
            refp[i, 1] = 3.0  # z0
            for axis in range(2):
                amax = 1.0 if axis == 0 else 0.5
                b = 3 + 9 * axis
                o = 13 + 9 * axis
                for k in range(3):
                    refp[i, b + k] = amax * u[i, o + k]
                    refp[i, b + 3 + k] = 0.2 + 0.6 * u[i, o + 3 + k]
                    refp[i, b + 6 + k] = two_pi * u[i, o + 6 + k]
            for k in range(5):
                q0[i, k] = 0.5 * dq[k]
                qd0[i, k] = 0.5 * dqd[k]
        for k in range(params.shape[0]):
            P[i, k] = params[k]
        if scale > 0:
            for k in range(8):
                col = _MISMATCH_COLUMNS[k]
                P[i, col] = P[i, col] * (1.0 + scale * (2.0 * u[i, 31 + k] - 1.0))
        key[i] = np.uint64(u[i, 46] * 2.0**53) ^ (np.uint64(u[i, 47] * 2.0**53) << np.uint64(11))


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


# ------------------------------------------------------------------------------ packed env state
# The state of N envs is a few arrays (few arguments: the call overhead of a compiled function grows
# with their number): F (N, F_LEN) float64 with the column blocks F_*, I (N, I_LEN) int64 (I_*),
# key (N,) uint64 and obs (N, 18) float32; constants C (C_*: the config vector cf, nominal params,
# gains, residual scales, control period) and K (K_* codes). BatchSim exposes the column blocks as
# views (sim.q, sim.qd, sim.qr, ...). In residual mode the controller's memory S (N, ST_LEN) and
# constants cc are those of the PassivityController object (control._kernels.controller_lanes).
# The kernels index F[n, column] directly: slicing rows into views would cost two atomic reference
# count updates per view, which dominated the step.
F_Q, F_QD, F_QM, F_QDM = 0, 5, 10, 15
F_QR, F_QDR, F_QDDR = 20, 25, 30  # reference now
F_QRN = 35  # the reference at the end of the step (q, qdot, qddot: 15), set before the step
F_LAG, F_APPLIED, F_WIND, F_CMD, F_U = 50, 55, 60, 62, 66
F_REW, F_TERMS, F_DIAG, F_P, F_T = 71, 72, 79, 87, 97
F_LEN = 98
I_COUNTER, I_STEPS, I_REASON, I_LAG_INIT, I_CLIPPED, I_LEN = range(6)
C_PNOM = CF_LEN
C_LAM = C_PNOM + 10
C_KG = C_LAM + 5
C_RES_TAU = C_KG + 5
C_DT = C_RES_TAU + 5
C_LEN = C_DT + 1
K_MODE, K_ALLOC, K_IMAP, K_RES_VIRTUAL, K_CONST_REF, K_ADIM, K_LEN = range(7)


@_jit
def _row5(A, n, c):
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4])


@_jit
def _row10(A, n, c):
    return (A[n, c], A[n, c + 1], A[n, c + 2], A[n, c + 3], A[n, c + 4],
            A[n, c + 5], A[n, c + 6], A[n, c + 7], A[n, c + 8], A[n, c + 9])


@_jit
def _vec5(v, c):
    return (v[c], v[c + 1], v[c + 2], v[c + 3], v[c + 4])


# ----------------------------------------------------------------------------------- observation
@_jit
def _wrap(a):
    """Angle wrapped to [-pi, pi): (a + pi) % 2 pi - pi, Python's float modulo. For a + pi already in
    [0, 2 pi) the modulo returns it unchanged (fmod is exact), so that case skips the modulo call
    (bit for bit the same result)."""
    x = a + math.pi
    if not (0.0 <= x < 2.0 * math.pi):
        x = x % (2.0 * math.pi)
    return x - math.pi


@_jit
def _clip_obs(v):
    return min(max(v, -OBS_CLIP), OBS_CLIP)


@_jit
def _observe_range(lo, hi, F, key, I, C, obs):
    """Measured state (noisy tiers: + Gaussian noise) into F's qm/qdm and the observation obs[n] of
    envs lo .. hi - 1."""
    noise = C[CF_FLAGS + 2] > 0.0
    for n in range(lo, hi):
        counter = I[n, I_COUNTER]
        for i in range(5):
            a = F[n, F_Q + i]
            b = F[n, F_QD + i]
            if noise:
                a = a + C[CF_NQ + i] * counter_normal(key[n], counter, i)
                b = b + C[CF_NQD + i] * counter_normal(key[n], counter, 5 + i)
            F[n, F_QM + i] = a
            F[n, F_QDM + i] = b
        obs[n, 0] = _clip_obs(F[n, F_QM] - F[n, F_QR])
        obs[n, 1] = _clip_obs(F[n, F_QM + 1] - F[n, F_QR + 1])
        obs[n, 2] = _clip_obs(_wrap(F[n, F_QM + 2] - F[n, F_QR + 2]))
        th = F[n, F_QM + 2]
        s_th, c_th = math.sin(th), math.cos(th)  # side by side: one sincos call
        obs[n, 3] = _clip_obs(s_th)
        obs[n, 4] = _clip_obs(c_th)
        obs[n, 5] = _clip_obs(F[n, F_QM + 3])
        obs[n, 6] = _clip_obs(F[n, F_QM + 4])
        for i in range(5):
            obs[n, 7 + i] = _clip_obs(F[n, F_QDM + i])
        for i in range(3):
            obs[n, 12 + i] = _clip_obs(F[n, F_QDR + i])
            obs[n, 15 + i] = _clip_obs(F[n, F_QDDR + i])


@MK._inline
def _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """(total energy of the plant, controller storage w.r.t. the body reference with arm references 0)."""
    energy = MK.kinetic_energy(q, qd, P) + MK.potential_energy(q, P)
    storage = CK.storage(q, qd, (qr[0], qr[1], qr[2], 0.0, 0.0), (qdr[0], qdr[1], qdr[2], 0.0, 0.0), Pnom, lam, kg)
    return energy, storage


@_jit
def energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg):
    """:func:`_energy_storage` as a compiled call (tuples: q, qd (5), qr, qdr (3), P, Pnom (10), lam,
    kg (5)): the non-inlined copy, shared by partial lane blocks and resets (inlining costs compile time)."""
    return _energy_storage(q, qd, qr, qdr, P, Pnom, lam, kg)


@_jit
def _diag_row(F, n, C):
    e, v = energy_storage(_row5(F, n, F_Q), _row5(F, n, F_QD), (F[n, F_QR], F[n, F_QR + 1], F[n, F_QR + 2]),
                          (F[n, F_QDR], F[n, F_QDR + 1], F[n, F_QDR + 2]), _row10(F, n, F_P),
                          _vec5(C, C_PNOM) + _vec5(C, C_PNOM + 5), _vec5(C, C_LAM), _vec5(C, C_KG))
    F[n, F_DIAG + D_ENERGY] = e
    F[n, F_DIAG + D_STORAGE] = v
    F[n, F_DIAG + D_CURV_VIOL] = max(abs(F[n, F_Q + 3]) - math.pi, abs(F[n, F_Q + 4]) - math.pi, 0.0)


@njit(cache=True, nogil=True)
def reset_rows(F, obs, key, I, C, rows, q0, qd0, P, keys, qr, qdr, qddr):
    """Start new episodes in the given rows (initial state, plant params, noise keys and reference
    at t = 0, row j of the inputs for rows[j]): clear the episode state, draw the initial wind,
    compute the observation, measured state and diagnostics."""
    std = C[CF_WIND_STD]
    for j in range(rows.shape[0]):
        n = rows[j]
        for i in range(5):
            F[n, F_Q + i] = q0[j, i]
            F[n, F_QD + i] = qd0[j, i]
            F[n, F_QR + i] = qr[j, i]
            F[n, F_QDR + i] = qdr[j, i]
            F[n, F_QDDR + i] = qddr[j, i]
            F[n, F_LAG + i] = 0.0
            F[n, F_APPLIED + i] = math.nan
        for i in range(10):
            F[n, F_P + i] = P[j, i]
        key[n] = keys[j]
        I[n, I_COUNTER] = 0
        I[n, I_STEPS] = 0
        I[n, I_LAG_INIT] = 1
        I[n, I_CLIPPED] = 0
        I[n, I_REASON] = R_NONE
        F[n, F_T] = 0.0
        F[n, F_REW] = 0.0
        for i in range(len(REWARD_TERMS)):
            F[n, F_TERMS + i] = 0.0
        for i in range(N_DIAG):
            F[n, F_DIAG + i] = 0.0
        # initial wind: stationary OU sample from the counter noise at counter 0
        if std > 0:
            F[n, F_WIND] = std * counter_normal(key[n], 0, 10)
            F[n, F_WIND + 1] = std * counter_normal(key[n], 0, 11)
        else:
            F[n, F_WIND] = 0.0
            F[n, F_WIND + 1] = 0.0
        _observe_range(n, n + 1, F, key, I, C, obs)
        _diag_row(F, n, C)


# ------------------------------------------------------------------------------------ step kernel
#: step kernel return codes
STEP_OK, STEP_BAD_ACTION, STEP_CONTROLLER_TAU, STEP_CONTROLLER_CURVATURE = range(4)
# lane rows of the physics block (after the RK4 rows of the model kernels): body reference (3),
# reference rates (3), energy, storage
L_QR = MK.LANE_ROWS_RK4
L_QDR = L_QR + 3
L_ENERGY = L_QDR + 3
L_STORAGE = L_ENERGY + 1
LANE_ROWS = L_STORAGE + 1
# per-row controller outputs in residual mode: actuators (4), allocation residual, arm references (2)
CTL_LEN = 7
# scratch of _begin_range: applied command (5), virtual tau (5)
CMD_WORK = 10


@_jit
def _virtual_allocation(F, n, C, alloc, imap, ws):
    """Virtual mode: thrusts from the body rows of tau (ws[5:10]) by the allocation, arm rows as
    generalized forces; the command into ws[0:4], diagnostics into F. Returns the thrust flag."""
    pnom = _vec5(C, C_PNOM) + _vec5(C, C_PNOM + 5)
    thrust_sat = 0.0
    if alloc == CK.ALLOC_PAPER:
        out, info = CK.allocate_paper(ws[5], ws[6], ws[7], F[n, F_Q + 2], pnom, 0.0, 0.0, False)
    else:
        out, info = CK.allocate_exact(ws[5], ws[6], ws[7], F[n, F_Q + 2], pnom, imap, 0.0, 0.0, False, math.pi)
    Tl, Tr = out[0], out[1]
    if not (math.isfinite(Tl) and math.isfinite(Tr)):
        Tl, Tr = 0.0, 0.0
        thrust_sat = 1.0
    ws[0], ws[1] = Tl, Tr
    F[n, F_DIAG + D_ALLOC_RES] = info[CK.INFO_RESIDUAL] if math.isfinite(info[CK.INFO_RESIDUAL]) else 1.0e300
    F[n, F_DIAG + D_ARM_L] = out[2]
    F[n, F_DIAG + D_ARM_R] = out[3]
    ws[2], ws[3] = ws[8], ws[9]
    if imap == MK.INPUT_MAP_EXACT:  # the arm rows get the requested generalized force
        gf = MK.generalized_forces(_row5(F, n, F_Q), (Tl, Tr, 0.0, 0.0), pnom, imap)
        ws[2] -= gf[3]
        ws[3] -= gf[4]
    return thrust_sat


@_jit
def _begin_range(lo, hi, F, I, C, K, ctl, W, ws):
    """Reference, clock and applied command (action scaling, allocation, saturation, actuator lag)
    of envs lo .. hi - 1, their state into the lanes of W."""
    mode, alloc, imap = K[K_MODE], K[K_ALLOC], K[K_IMAP]
    const_ref = K[K_CONST_REF] != 0
    dt_ctrl = C[C_DT]
    tmax = C[CF_TMAX]
    taumax = C[CF_TAUMAX]
    lag_on = C[CF_FLAGS] > 0.0
    L = MK.LANES
    for n in range(lo, hi):
        if not const_ref:
            for i in range(15):
                F[n, F_QR + i] = F[n, F_QRN + i]
        I[n, I_STEPS] += 1
        F[n, F_T] = I[n, I_STEPS] * dt_ctrl
        for i in range(5):  # ws[0:5]: the command: actuators (4) or, in ideal mode, tau (5)
            ws[i] = 0.0
        thrust_sat = 0.0
        torque_sat = 0.0
        F[n, F_DIAG + D_ALLOC_RES] = 0.0
        F[n, F_DIAG + D_ARM_L] = 0.0
        F[n, F_DIAG + D_ARM_R] = 0.0
        if mode == MODE_ACT:
            ws[0] = tmax * 0.5 * (F[n, F_U] + 1.0)
            ws[1] = tmax * 0.5 * (F[n, F_U + 1] + 1.0)
            ws[2] = taumax * F[n, F_U + 2]
            ws[3] = taumax * F[n, F_U + 3]
        elif mode == MODE_RES_ACT:
            for i in range(4):
                ws[i] = ctl[n, i] + C[CF_RES_ACT + i] * F[n, F_U + i]
        else:
            for i in range(5):
                ws[5 + i] = C[CF_OFFSET + i] + C[CF_SCALE + i] * F[n, F_U + i]
            if mode == MODE_IDEAL:
                for i in range(5):
                    ws[i] = ws[5 + i]
            else:
                thrust_sat = _virtual_allocation(F, n, C, alloc, imap, ws)
        na = 5 if mode == MODE_IDEAL else 4
        if mode != MODE_IDEAL:
            for i in range(2):
                if ws[i] < 0.0:
                    ws[i] = 0.0
                    thrust_sat = 1.0
                elif ws[i] > tmax:
                    ws[i] = tmax
                    thrust_sat = 1.0
            for i in range(2, 4):
                if ws[i] < -taumax:
                    ws[i] = -taumax
                    torque_sat = 1.0
                elif ws[i] > taumax:
                    ws[i] = taumax
                    torque_sat = 1.0
        F[n, F_DIAG + D_THRUST_SAT] = thrust_sat
        F[n, F_DIAG + D_TORQUE_SAT] = torque_sat
        # first-order actuator lag (starts at the first command of the episode)
        if lag_on:
            if I[n, I_LAG_INIT] != 0:
                for i in range(na):
                    F[n, F_LAG + i] = ws[i]
                I[n, I_LAG_INIT] = 0
            else:
                al = C[CF_LAG_A]
                for i in range(na):
                    F[n, F_LAG + i] = F[n, F_LAG + i] + al * (ws[i] - F[n, F_LAG + i])
            for i in range(na):
                ws[i] = F[n, F_LAG + i]
        for i in range(5):
            F[n, F_APPLIED + i] = ws[i] if i < na else math.nan
        if mode == MODE_RES_ACT:
            F[n, F_DIAG + D_ALLOC_RES] = ctl[n, 4]
            F[n, F_DIAG + D_ARM_L] = ctl[n, 5]
            F[n, F_DIAG + D_ARM_R] = ctl[n, 6]
        j = n - lo
        for i in range(5):
            W[(MK.LANE_Q + i) * L + j] = F[n, F_Q + i]
            W[(MK.LANE_QD + i) * L + j] = F[n, F_QD + i]
        for i in range(10):
            W[(MK.LANE_P + i) * L + j] = F[n, F_P + i]


@_jit
def _lane_put5(W, row, j, v):
    L = MK.LANES
    W[row * L + j] = v[0]
    W[(row + 1) * L + j] = v[1]
    W[(row + 2) * L + j] = v[2]
    W[(row + 3) * L + j] = v[3]
    W[(row + 4) * L + j] = v[4]


@_jit
def _lane5(W, row, j):
    L = MK.LANES
    o = row * L + j
    return (W[o], W[o + L], W[o + 2 * L], W[o + 3 * L], W[o + 4 * L])


@MK._inline
def _diag_lane_in(W, j):
    q, qd, _u, _ext, p = MK._lane_load(W, j)
    L = MK.LANES
    qr = (W[L_QR * L + j], W[(L_QR + 1) * L + j], W[(L_QR + 2) * L + j])
    qdr = (W[L_QDR * L + j], W[(L_QDR + 1) * L + j], W[(L_QDR + 2) * L + j])
    return q, qd, qr, qdr, p


@_jit
def _diag_lanes(W, m, pnom, lam, kg):
    """Energy and storage of the first m lanes (the functions of _diag_row; SIMD for full blocks)."""
    L = MK.LANES
    if m == L:
        for j in range(L):
            q, qd, qr, qdr, p = _diag_lane_in(W, j)
            W[L_ENERGY * L + j], W[L_STORAGE * L + j] = _energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)
    else:
        for j in range(m):
            q, qd, qr, qdr, p = _diag_lane_in(W, j)
            W[L_ENERGY * L + j], W[L_STORAGE * L + j] = energy_storage(q, qd, qr, qdr, p, pnom, lam, kg)


@_jit
def _physics_range(lo, hi, F, C, K, W):
    """frame_skip RK4 steps of envs lo .. hi - 1 in the lanes of W with the applied command and the
    wind held (zero-order hold): held actuators go through B(q) at every RK4 stage; in ideal mode the
    generalized force itself is held."""
    L = MK.LANES
    held = MK.HELD_TAU if K[K_MODE] == MODE_IDEAL else K[K_IMAP]
    for n in range(lo, hi):
        j = n - lo
        for i in range(5):  # (a 4-entry actuator command has NaN in F's fifth entry: pad with 0)
            W[(MK.LANE_U + i) * L + j] = F[n, F_APPLIED + i] if (i < 4 or held == MK.HELD_TAU) else 0.0
        W[MK.LANE_EXT * L + j] = F[n, F_WIND]  # (0 unless the wind is on)
        W[(MK.LANE_EXT + 1) * L + j] = F[n, F_WIND + 1]
    for _ in range(int(C[CF_FS])):
        MK.rk4_lanes(W, C[CF_DT], hi - lo, held)


@_jit
def _end_range(lo, hi, F, key, I, C, W):
    """Clock, wind and termination of envs lo .. hi - 1; the final state from W back into F (the last
    finite one if it diverged, also into W); the body reference into W for the diagnostics."""
    L = MK.LANES
    wind_on = C[CF_FLAGS + 1] > 0.0
    for n in range(lo, hi):
        j = n - lo
        I[n, I_COUNTER] += 1
        counter = I[n, I_COUNTER]
        if wind_on:
            wa, wb = C[CF_WIND_A], C[CF_WIND_B]
            F[n, F_WIND] = wa * F[n, F_WIND] + wb * counter_normal(key[n], counter, 10)
            F[n, F_WIND + 1] = wa * F[n, F_WIND + 1] + wb * counter_normal(key[n], counter, 11)
        q = _lane5(W, MK.LANE_Q, j)
        qd = _lane5(W, MK.LANE_QD, j)
        finite = True
        for i in range(5):
            if not (math.isfinite(q[i]) and math.isfinite(qd[i])):
                finite = False
        reason = R_NONE
        if not finite:
            reason = R_NONFINITE  # keep the last finite state: observation and info stay finite
            for i in range(5):
                W[(MK.LANE_Q + i) * L + j] = F[n, F_Q + i]
                W[(MK.LANE_QD + i) * L + j] = F[n, F_QD + i]
        else:
            F[n, F_Q], F[n, F_Q + 1], F[n, F_Q + 2], F[n, F_Q + 3], F[n, F_Q + 4] = q
            F[n, F_QD], F[n, F_QD + 1], F[n, F_QD + 2], F[n, F_QD + 3], F[n, F_QD + 4] = qd
            if abs(q[3]) > math.pi or abs(q[4]) > math.pi:
                reason = R_CURV
            elif q[1] < GROUND_Z:
                reason = R_GROUND
            elif (abs(q[0]) > BOX_X or q[1] > BOX_Z or abs(qd[0]) > MAX_LIN_SPEED or abs(qd[1]) > MAX_LIN_SPEED
                  or abs(qd[2]) > MAX_ANG_SPEED or abs(qd[3]) > MAX_ANG_SPEED or abs(qd[4]) > MAX_ANG_SPEED):
                reason = R_OOB
        I[n, I_REASON] = reason
        for i in range(3):
            W[(L_QR + i) * L + j] = F[n, F_QR + i]
            W[(L_QDR + i) * L + j] = F[n, F_QDR + i]


@_jit
def _reward_range(lo, hi, F, I, C, K, W):
    """Diagnostics (energy and storage from the lanes of W) and reward terms of envs lo .. hi - 1
    (true state, not the noisy measurement)."""
    L = MK.LANES
    ideal = K[K_MODE] == MODE_IDEAL
    tmax = C[CF_TMAX]
    taumax = C[CF_TAUMAX]
    for n in range(lo, hi):
        j = n - lo
        q3, q4 = F[n, F_Q + 3], F[n, F_Q + 4]
        F[n, F_DIAG + D_ENERGY] = W[L_ENERGY * L + j]
        F[n, F_DIAG + D_STORAGE] = W[L_STORAGE * L + j]
        F[n, F_DIAG + D_CURV_VIOL] = max(abs(q3) - math.pi, abs(q4) - math.pi, 0.0)
        ex, ez = F[n, F_Q] - F[n, F_QR], F[n, F_Q + 1] - F[n, F_QR + 1]
        eth = _wrap(F[n, F_Q + 2] - F[n, F_QR + 2])
        ev = math.sqrt((F[n, F_QD] - F[n, F_QDR]) ** 2 + (F[n, F_QD + 1] - F[n, F_QDR + 1]) ** 2
                       + (F[n, F_QD + 2] - F[n, F_QDR + 2]) ** 2)
        if ideal:
            eff = 0.0
            for i in range(5):
                eff += ((F[n, F_APPLIED + i] - C[CF_OFFSET + i]) / C[CF_SCALE + i]) ** 2
            eff /= 5.0
        else:
            th = C[CF_THOVER]
            eff = 0.25 * (((F[n, F_APPLIED] - th) / tmax) ** 2 + ((F[n, F_APPLIED + 1] - th) / tmax) ** 2
                          + (F[n, F_APPLIED + 2] / taumax) ** 2 + (F[n, F_APPLIED + 3] / taumax) ** 2)
        cm = max(abs(q3), abs(q4))
        cp = min(max((cm - 0.5 * math.pi) / (0.5 * math.pi), 0.0), 1.0)
        t0 = 1.0
        t1 = -W_POS * min(math.sqrt(ex * ex + ez * ez) / POS_SCALE, 1.0)
        t2 = -W_ATT * min(abs(eth) / math.pi, 1.0)
        t3 = -W_VEL * min(ev / VEL_SCALE, 1.0)
        t4 = -W_EFFORT * min(eff, 1.0)
        t5 = -W_CURV * cp * cp
        t6 = -CRASH_PENALTY if I[n, I_REASON] != R_NONE else 0.0
        F[n, F_TERMS], F[n, F_TERMS + 1], F[n, F_TERMS + 2], F[n, F_TERMS + 3] = t0, t1, t2, t3
        F[n, F_TERMS + 4], F[n, F_TERMS + 5], F[n, F_TERMS + 6] = t4, t5, t6
        r = 0.0
        r += t0
        r += t1
        r += t2
        r += t3
        r += t4
        r += t5
        r += t6
        F[n, F_REW] = r


@_jit
def _step_block(n0, m, F, obs, key, I, C, K, ctl, W, ws):
    """Advance envs n0 .. n0 + m - 1 (m <= LANES) by one control step; the physics of the block runs
    in the lane buffer W (structure-of-arrays, rows MK.LANE_* and L_*)."""
    hi = n0 + m
    _begin_range(n0, hi, F, I, C, K, ctl, W, ws)
    _physics_range(n0, hi, F, C, K, W)
    _end_range(n0, hi, F, key, I, C, W)
    _diag_lanes(W, m, _vec5(C, C_PNOM) + _vec5(C, C_PNOM + 5), _vec5(C, C_LAM), _vec5(C, C_KG))
    _observe_range(n0, hi, F, key, I, C, obs)
    _reward_range(n0, hi, F, I, C, K, W)


@_jit
def _check_actions(act, adim):
    """(all actions finite, any clipped action nonzero): read only, so a bad action changes nothing."""
    anyu = False
    for i in range(act.shape[0]):
        for k in range(adim):
            x = act[i, k]
            if not math.isfinite(x):
                return False, False
            if x != 0.0:  # the clipped value is nonzero exactly when x is (x finite)
                anyu = True
    return True, anyu


@_jit
def _clip_actions(lo, hi, act, F, I, adim):
    """Clip the actions of envs lo .. hi - 1 to [-1, 1] into F's action block; flag clipped rows."""
    for i in range(lo, hi):
        clipped = 0
        for k in range(adim):
            x = act[i, k]
            c = -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)
            F[i, F_U + k] = c
            if c != x:
                clipped = 1
        I[i, I_CLIPPED] = clipped


@_jit
def _controller_rows(lo, hi, F, C, has_res, cc, S, S_new, ctl, err):
    """The residual-mode base controller (PassivityController's block kernel, fed the measured state)
    for envs lo .. hi - 1: actuators, allocation residual and arm references into ctl, the new memory
    into S_new."""
    cfg, p, lam, kg = CK.config_tuples(cc)
    zero = (0.0, 0.0, 0.0, 0.0, 0.0)
    B, A = CK.controller_work()
    for n0 in range(lo, hi, CK.CTRL_LANES):
        m = min(CK.CTRL_LANES, hi - n0)
        for j in range(m):
            n = n0 + j
            res = zero
            if has_res:
                res = (F[n, F_U] * C[C_RES_TAU], F[n, F_U + 1] * C[C_RES_TAU + 1], F[n, F_U + 2] * C[C_RES_TAU + 2],
                       F[n, F_U + 3] * C[C_RES_TAU + 3], F[n, F_U + 4] * C[C_RES_TAU + 4])
            CK.put_lane_inputs(B, j, _row5(F, n, F_QM), _row5(F, n, F_QDM), _row5(F, n, F_QR), _row5(F, n, F_QDR),
                               _row5(F, n, F_QDDR), res, S, n)
        CK.controller_lanes(m, B, A, has_res, True, cfg, p, lam, kg)
        for j in range(m):
            n = n0 + j
            err[n] = CK.ERR_NONE
            if B[CK.lane_index(CK.CB_ERR, j)] != CK.ERR_NONE:
                # a non-finite or out-of-model measured state (a diverged env: one that terminated and
                # is stepped once more before its autoreset, or stepped past termination): NaN
                # actuators, so that the physics ends the episode as "non_finite" instead of the step
                # raising; the row's controller memory stays as it was (the block kernel's choice)
                for k in range(CTL_LEN):
                    ctl[n, k] = math.nan
            else:
                ctl[n, 0], ctl[n, 1], ctl[n, 2], ctl[n, 3] = CK.lane4(B, CK.CB_ACT, j)
                ctl[n, 4] = B[CK.lane_index(CK.CB_INFO + CK.INFO_RESIDUAL, j)]
                ctl[n, 5], ctl[n, 6] = B[CK.lane_index(CK.CB_ARM, j)], B[CK.lane_index(CK.CB_ARM + 1, j)]
            CK.put_lane_memory(B, j, S_new, n)


@_jit
def _controller_error(err, S, S_new):
    """Commit the controller memory if every row succeeded; else the step kernel's error code."""
    for n in range(err.shape[0]):
        if err[n] == CK.ERR_TAU:
            return STEP_CONTROLLER_TAU
        if err[n] == CK.ERR_CURVATURE:
            return STEP_CONTROLLER_CURVATURE
    for n in range(S.shape[0]):
        for k in range(CK.ST_LEN):
            S[n, k] = S_new[n, k]
    return STEP_OK


@_jit
def _physics_rows(lo, hi, F, obs, key, I, C, K, ctl):
    """Advance envs lo .. hi - 1 by one control step, in blocks of LANES (the controller done)."""
    W = np.empty(LANE_ROWS * MK.LANES)
    ws = np.empty(CMD_WORK)
    for n0 in range(lo, hi, MK.LANES):
        _step_block(n0, min(MK.LANES, hi - n0), F, obs, key, I, C, K, ctl, W, ws)


# Entry points. Small batches: step_serial (one call). Large batches: BatchSim splits the rows over
# threads (Python threads calling these nogil kernels on disjoint row ranges, waiting passively;
# numba's OpenMP pool spin-waits, which collapses when the machine is busy):
# step_check_actions, then (residual mode) step_controller_rows + step_commit_controller, then
# step_physics_rows. An error code changes nothing (but the clipped action of the controller phase).


@njit(cache=True, nogil=True)
def step_check_actions(act, K):
    """(all actions finite, a tau residual is added) (see _check_actions)."""
    ok, anyu = _check_actions(act, K[K_ADIM])
    return ok, anyu and K[K_RES_VIRTUAL] != 0


@njit(cache=True, nogil=True)
def step_controller_rows(lo, hi, act, F, I, C, K, has_res, cc, S, S_new, ctl, err):
    """Residual mode, envs lo .. hi - 1: clip the actions, then the base controller."""
    _clip_actions(lo, hi, act, F, I, K[K_ADIM])
    _controller_rows(lo, hi, F, C, has_res, cc, S, S_new, ctl, err)


@njit(cache=True, nogil=True)
def step_commit_controller(err, S, S_new):
    return _controller_error(err, S, S_new)


@njit(cache=True, nogil=True)
def step_physics_rows(lo, hi, act, F, obs, key, I, C, K, ctl):
    """Envs lo .. hi - 1: clip the actions (unless the controller phase did), then the step."""
    if K[K_MODE] != MODE_RES_ACT:
        _clip_actions(lo, hi, act, F, I, K[K_ADIM])
    _physics_rows(lo, hi, F, obs, key, I, C, K, ctl)


@njit(cache=True, nogil=True)
def step_serial(act, F, obs, key, I, C, K, cc, S):
    """One control step of every env (actions act (N, A)); returns a ``STEP_*`` code."""
    n = F.shape[0]
    ok, anyu = _check_actions(act, K[K_ADIM])
    if not ok:
        return STEP_BAD_ACTION
    _clip_actions(0, n, act, F, I, K[K_ADIM])
    ctl = np.empty((n, CTL_LEN))
    if K[K_MODE] == MODE_RES_ACT:
        S_new = S.copy()
        err = np.zeros(n, dtype=np.int64)
        _controller_rows(0, n, F, C, anyu and K[K_RES_VIRTUAL] != 0, cc, S, S_new, ctl, err)
        code = _controller_error(err, S, S_new)
        if code != STEP_OK:
            return code
    _physics_rows(0, n, F, obs, key, I, C, K, ctl)
    return STEP_OK


#: batches of at least this many envs are split over threads (softpvtol_gym._parallel)
PARALLEL_THRESHOLD = MIN_ROWS


# ----------------------------------------------------------------------------------- batch state
class BatchSim:
    """State of N envs as arrays and their step/reset, shared by the single and the vector env.

    The state lives in a few packed arrays (see the step kernel); the attributes q, qd, qm, qdm, qr,
    qdr, qddr, lag, applied, wind, cmd, u, rew, terms, diag, P, t (float) and counter, steps, reason,
    lag_init, clipped (int) are views into them.
    """

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
        self._const_ref = cfg.task in ("hover", "setpoint")
        # packed state and its views
        self.F = np.zeros((n, F_LEN))
        self.I = np.zeros((n, I_LEN), dtype=np.int64)
        self.key = np.zeros(n, dtype=np.uint64)
        self.obs = np.zeros((n, OBS_DIM), dtype=np.float32)
        self._make_views()
        self.P[:] = self.Pnom
        self.lag_init[:] = 1
        self.refp = np.zeros((n, N_REF_PARAMS))
        C = np.zeros(C_LEN)
        C[:CF_LEN] = self.cf
        C[C_PNOM:C_PNOM + 10] = self.Pnom
        C[C_LAM:C_LAM + 5] = self.lam
        C[C_KG:C_KG + 5] = self.kg
        C[C_RES_TAU:C_RES_TAU + 5] = cfg.residual_tau_scale
        C[C_DT] = self.dt
        self.C = C
        K = np.zeros(K_LEN, dtype=np.int64)
        K[K_MODE], K[K_ALLOC], K[K_IMAP] = self.mode, self.alloc_code, self.imap
        K[K_RES_VIRTUAL] = 1 if cfg.residual_space == "virtual" else 0
        K[K_CONST_REF] = 1 if self._const_ref else 0
        K[K_ADIM] = self.action_dim
        self.K = K
        self._ranges = row_ranges(n, align=MK.LANES)  # one per thread, whole lane blocks
        self._ctl = np.empty((n, CTL_LEN)) if len(self._ranges) > 1 else None
        self._shape = {True: (n, self.action_dim), False: (self.action_dim,)}
        self.controller = None
        if cfg.action_mode == "residual":
            self.controller = PassivityController.from_loop(
                cfg.controller_loop, params=cfg.params, input_map=cfg.input_map, dt=cfg.dt
            )
            self.controller.state_rows(n)

    _VIEWS = ("q", "qd", "qm", "qdm", "qr", "qdr", "qddr", "qr_next", "lag", "applied", "wind", "cmd", "u", "rew",
              "terms", "diag", "P", "t", "counter", "steps", "reason", "lag_init", "clipped")

    def _make_views(self) -> None:
        F, I = self.F, self.I
        self.q, self.qd, self.qm, self.qdm = F[:, F_Q:F_Q + 5], F[:, F_QD:F_QD + 5], F[:, F_QM:F_QM + 5], F[:, F_QDM:F_QDM + 5]
        self.qr, self.qdr, self.qddr = F[:, F_QR:F_QR + 5], F[:, F_QDR:F_QDR + 5], F[:, F_QDDR:F_QDDR + 5]
        self.qr_next = F[:, F_QRN:F_QRN + 15]
        self.lag, self.applied = F[:, F_LAG:F_LAG + 5], F[:, F_APPLIED:F_APPLIED + 5]
        self.wind, self.cmd = F[:, F_WIND:F_WIND + 2], F[:, F_CMD:F_CMD + 4]
        self.u = F[:, F_U:F_U + self.action_dim]
        self.rew, self.terms = F[:, F_REW], F[:, F_TERMS:F_TERMS + len(REWARD_TERMS)]
        self.diag, self.P, self.t = F[:, F_DIAG:F_DIAG + N_DIAG], F[:, F_P:F_P + 10], F[:, F_T]
        self.counter, self.steps, self.reason = I[:, I_COUNTER], I[:, I_STEPS], I[:, I_REASON]
        self.lag_init, self.clipped = I[:, I_LAG_INIT], I[:, I_CLIPPED]

    def __getstate__(self) -> dict:
        # the views are rebuilt on unpickling (pickle would turn them into independent copies)
        return {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_views()

    # -------------------------------------------------------------------------------- reset
    def reset_entries(self, idx: np.ndarray, u: np.ndarray, options: dict | None = None) -> None:
        """Start new episodes in entries ``idx`` from uniforms ``u`` (len(idx), N_UNIFORMS)."""
        self.apply_reset(idx, self.prepare_reset(u, options))

    def prepare_reset(self, u: np.ndarray, options: dict | None = None) -> dict:
        """The new episodes of :meth:`reset_entries` (changes nothing yet)."""
        ep = sample_episodes(self.cfg, u)
        if options:
            ep = _apply_options(self.cfg, ep, options)
        ep["ref"] = tuple(np.ascontiguousarray(r) for r in reference(self.cfg.task, np.zeros(u.shape[0]), ep["refp"]))
        return ep

    def apply_reset(self, idx: np.ndarray, ep: dict) -> None:
        """Write episodes from :meth:`prepare_reset` into entries ``idx``."""
        rows = np.arange(self.n)[idx] if not isinstance(idx, np.ndarray) else idx
        rows = np.ascontiguousarray(np.atleast_1d(rows), dtype=np.int64)
        self.refp[rows] = ep["refp"]
        qr, qdr, qddr = ep["ref"]
        reset_rows(self.F, self.obs, self.key, self.I, self.C, rows, ep["q0"], ep["qd0"], ep["P"], ep["key"], qr, qdr,
                   qddr)
        if self.controller is not None:
            self.controller.reset_rows(rows)

    # --------------------------------------------------------------------------------- step
    def step(self, action, batched: bool, side=None) -> None:
        """Validate the action (shape, finite), clip it and advance every entry by one control step.

        ``side()``, if given, runs in this thread once the step cannot fail any more, beside the
        kernel threads of a large batch (Python work that overlaps the physics)."""
        expected = self._shape[batched]
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
        if not batched:
            a = a.reshape(1, self.action_dim)
        if not self._const_ref:
            t_next = (self.steps + 1) * self.dt
            qr, qdr, qddr = reference(self.cfg.task, t_next, self.refp)
            nx = self.qr_next
            nx[:, 0:5], nx[:, 5:10], nx[:, 10:15] = qr, qdr, qddr
        ctrl = self.controller
        if ctrl is not None:
            cc, S = ctrl.kernel_constants, ctrl.state_rows(self.n)
        else:
            cc, S = self.C, self.F
        if len(self._ranges) == 1:
            code = step_serial(a, self.F, self.obs, self.key, self.I, self.C, self.K, cc, S)
            if code == STEP_OK and side is not None:
                side()
        else:
            code = self._step_split(a, cc, S, side)
        if code != STEP_OK:
            if code == STEP_BAD_ACTION:
                raise ValueError(f"action must be finite (in [-1, 1]), got {action!r}")
            if code == STEP_CONTROLLER_TAU:
                raise ValueError("tau contains NaN or inf; allocation needs a finite body force")
            check_curvature(self.qm)
            raise RuntimeError(f"step kernel failed with code {code}")  # pragma: no cover

    def _step_split(self, a, cc, S, side=None) -> int:
        """The step of a large batch with its rows split over threads (same result as step_serial)."""
        F, obs, key, I, C, K, ctl = self.F, self.obs, self.key, self.I, self.C, self.K, self._ctl
        ok, has_res = step_check_actions(a, K)
        if not ok:
            return STEP_BAD_ACTION
        if self.controller is not None:
            S_new = S.copy()
            err = np.zeros(self.n, dtype=np.int64)
            run_split(lambda lo, hi: step_controller_rows(lo, hi, a, F, I, C, K, has_res, cc, S, S_new, ctl, err),
                      self._ranges)
            code = step_commit_controller(err, S, S_new)
            if code != STEP_OK:
                return code
        run_split(lambda lo, hi: step_physics_rows(lo, hi, a, F, obs, key, I, C, K, ctl), self._ranges, side)
        return STEP_OK


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
