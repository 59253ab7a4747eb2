"""The env's packed arrays, declared once (see :class:`softpvtol_gym._columns.Columns`).

The state of N envs is ``F`` (N, STATE.size) float64, ``I`` (N, ISTATE.size) int64, ``key`` (N,)
uint64 (per-episode noise keys) and ``obs`` (N, OBS_DIM) float32; the constants of a config are ``C``
(CONST.size) float64 and ``K`` (CODES.size) int64. The kernels index ``F[n, S.q + i]`` with the
column constants below (``S = STATE.at``: numba freezes them at compile time); BatchSim exposes the
fields as named views (``sim.q``, ``sim.wind``, ...). Slicing rows into views inside the kernels
would cost two atomic reference-count updates per view, which dominated the step.
"""

from __future__ import annotations

from .. import model as MK
from .._columns import Columns
from ..references import N_REF_PARAMS
from .reward import REWARD_TERMS

STATE = Columns("env_state", [
    ("q", 5), ("qd", 5),  # true state
    ("qm", 5), ("qdm", 5),  # measured state (noise tiers: + noise)
    ("qr", 5), ("qdr", 5), ("qddr", 5),  # reference now (arm entries 0)
    ("qr_custom", 9),  # a custom task's reference at the end of the step (pos, vel, acc: 3 each), set before it
    ("refp", N_REF_PARAMS),  # per-episode reference parameters
    ("lag", 5), ("applied", 5), ("wind", 2), ("u", 5),  # lag state, applied command, wind force, clipped action
    ("reward", 1), ("terms", len(REWARD_TERMS)),
    # diagnostics
    ("allocation_residual", 1), ("thrust_saturated", 1), ("arm_torque_saturated", 1), ("total_energy", 1),
    ("storage_function", 1), ("curvature_violation", 1), ("arm_reference", 2),
    ("P", 10), ("t", 1),  # plant parameters, episode time
], version=2)
ISTATE = Columns("env_int_state", [("counter", 1), ("steps", 1), ("reason", 1), ("lag_init", 1), ("clipped", 1)],
                version=1)
CONST = Columns("env_constants", [
    ("dt_physics", 1), ("frame_skip", 1), ("thrust_max", 1), ("arm_torque_max", 1),
    ("lag_a", 1), ("wind_a", 1), ("wind_b", 1), ("wind_std", 1),  # lag and OU wind coefficients
    ("noise_q", 5), ("noise_qd", 5),  # observation-noise stds
    ("virtual_scale", 5), ("virtual_offset", 5), ("residual_actuator_scale", 4), ("residual_tau_scale", 5),
    ("hover_thrust", 1), ("lag_on", 1), ("wind_on", 1), ("noise_on", 1),
    ("p_nominal", 10), ("lam", 5), ("kg", 5), ("dt_control", 1),
    ("consistent_plant", 1),  # 1.0: the plant integrates the consistent model (docs/model.md)
    ("residual_base_saturated", 1),  # 1.0: an actuator-space residual is added to the base command clipped to the box
], version=3)
CODES = Columns("env_codes", [("mode", 1), ("alloc", 1), ("imap", 1), ("res_virtual", 1), ("ref", 1),
                             ("action_dim", 1)], version=1)
#: the physics lane block of a step: the RK4 rows, then the body reference and rates for the
#: energy/storage diagnostics and their results
LANES = MK.RK4_LANES.extend("env_lanes", [("qr", 3), ("qdr", 3), ("energy", 1), ("storage", 1)])

S, SI, SC, SK, SL = STATE.at, ISTATE.at, CONST.at, CODES.at, LANES.at
