"""Compiled physics kernels: the single source of truth of the Soft-PVTOL model.

Everything physical (D, C, g, the input maps, forward dynamics, energies, tip positions, the RK4 step)
is written once here as numba-compiled functions of one state and the flat parameter vector
``p = SoftPVTOLParams.array``. The public batched API (:mod:`softpvtol_gym.dynamics`,
:mod:`softpvtol_gym.integrators`), the env, the vector env and the controller all call these.

Modules, by job (imports point down this list):

================  ======================================================================================
:mod:`.jit`        the numba decorators (``jit``, ``inline``, ``batch_jit``): one set of compile options
:mod:`.series`     the arms' curvature series (Horner's rule), ``sin_cos`` and ``rotate`` built on it
:mod:`.paper`      the paper's model: D, C, g entries and the forward dynamics ``qddot``
:mod:`.consistent` the consistent model (tips rotated with theta): D, C, g and ``consistent_qddot``
:mod:`.input_map`  tau = B(q) a (``INPUT_MAP_PAPER``, ``INPUT_MAP_EXACT``) and the held force of a stage
:mod:`.energies`   kinetic and potential energy of both models
:mod:`.kinematics` tip positions
:mod:`.rk4`        the RK4 step with the command held, on tuples and arrays, of both models
:mod:`.lanes`      SIMD lane blocks (``LANES`` states structure-of-arrays) stepped by one loop
:mod:`.batched`    the batched wrappers behind the public API (``MODEL_PAPER``, ``MODEL_CONSISTENT``)
================  ======================================================================================

This package gathers their names, so that callers write ``from softpvtol_gym import model as MK`` and
``MK.rk4_lanes``. The parameter vector is indexed by the names of :mod:`softpvtol_gym.params`
(``P_M``, ``P_ML``, ... in ``PARAM_FIELDS`` order), never by bare numbers.

Why numba: the model is a few dozen flops per state, so NumPy's per-call overhead (~1 us per ufunc on
tiny arrays) would dominate both the single env (hundreds of ufunc calls per RK4 step) and batched
rollouts (many temporaries). ``njit(cache=True)`` compiles the scalar code once per machine, keeps one
copy of the physics for single and batched use, and ``fastmath`` stays off so that results are bit for
bit identical between the single env and every sub-env of the vector env.

Two models: the paper's (the functions without prefix; its rotor masses on tips that do not rotate
with theta) and the consistent one (``consistent_*``: the same energy terms with the tips rotated by
theta; docs/model.md). The env's SIMD lane step is the paper model's; the consistent one runs lane by
lane (:func:`rk4_lanes_consistent`).

Conventions: q = (x, z, theta, q_l, q_r); p in ``PARAM_FIELDS`` order
(m, m_l, m_r, I, I_l, I_r, l_l, l_r, g, epsilon); actuators a = (T_l, T_r, tau_l, tau_r).

Speed (see ``benchmarks/``): the small, pure-arithmetic functions (series, D entries, qddot, the RK4
step, energies) are inlined into their callers (``inline="always"``) and take arrays *or* tuples, so a
loop over a block of ``LANES`` states stored structure-of-arrays (:func:`rk4_lanes`) compiles to SIMD
code. The series polynomial :func:`horner` is the exception: a plain compiled call that LLVM inlines
(numba's own inliner re-types and copies each of its few hundred inlined copies per kernel, which was
most of the cold compile time). Every lane performs exactly the scalar IEEE operations (no fastmath,
no FMA contraction), so the SIMD path is bit-identical to the scalar one; the tests check it.
"""

from __future__ import annotations

from ..params import N_PARAMS, P_EPS, P_G, P_I, P_IL, P_IR, P_LL, P_LR, P_M, P_ML, P_MR
from .batched import (
    MODEL_CONSISTENT,
    MODEL_PAPER,
    batch_coriolis_matrix,
    batch_energies,
    batch_forward_dynamics,
    batch_generalized_forces,
    batch_gravity_vector,
    batch_mass_matrix,
    batch_rk4_step,
    batch_tip_positions,
)
from .consistent import (
    consistent_arm,
    consistent_arms,
    consistent_bias_arm,
    consistent_coriolis_matrix_into,
    consistent_forward_dynamics_into,
    consistent_gravity_entries,
    consistent_gravity_vector_into,
    consistent_mass_entries,
    consistent_mass_matrix_into,
    consistent_qddot,
)
from .energies import (
    consistent_energies,
    consistent_kinetic_energy,
    consistent_potential_energy,
    kinetic_energy,
    potential_energy,
)
from .input_map import (
    HELD_TAU,
    INPUT_MAP_EXACT,
    INPUT_MAP_PAPER,
    generalized_forces,
    generalized_forces_into,
    generalized_forces_sc,
    held_force,
    thrust_body_forces,
    thrust_curvature_work,
)
from .jit import accessor, batch_jit, inline, jit
from .kinematics import arm_offset, paper_tip_positions_into, tip_positions_into
from .lanes import (
    LANE_EXT,
    LANE_P,
    LANE_Q,
    LANE_QD,
    LANE_ROWS_RK4,
    LANE_SC,
    LANE_U,
    LANES,
    RK4_LANES,
    lane_load,
    lane_store,
    rk4_lanes,
    rk4_lanes_consistent,
    rk4_lanes_partial,
)
from .paper import (
    coriolis_entries,
    coriolis_entries_basis,
    coriolis_matrix_into,
    forward_dynamics_into,
    gravity_entries,
    gravity_entries_basis,
    gravity_vector_into,
    mass_entries,
    mass_entries_basis,
    mass_matrix_into,
    qddot,
)
from .rk4 import (
    consistent_rk4_step,
    consistent_rk4_step_into,
    consistent_rk4_step_tuple,
    consistent_stage,
    rk4_step,
    rk4_step_into,
    rk4_step_sc,
    rk4_step_tuple,
)
from .series import (
    A_COEFFS,
    C1_COEFFS,
    D1P_COEFFS,
    D2_COEFFS,
    D2PQ_COEFFS,
    HORNER_TERMS,
    S0_COEFFS,
    TWO_PI,
    arm_basis,
    horner,
    one_minus_cos_over_q2,
    rotate,
    sin_cos,
    sinc,
)

__all__ = [
    "N_PARAMS", "P_EPS", "P_G", "P_I", "P_IL", "P_IR", "P_LL", "P_LR", "P_M", "P_ML", "P_MR", "MODEL_CONSISTENT",
    "MODEL_PAPER", "batch_coriolis_matrix", "batch_energies", "batch_forward_dynamics", "batch_generalized_forces",
    "batch_gravity_vector", "batch_mass_matrix", "batch_rk4_step", "batch_tip_positions", "consistent_arm",
    "consistent_arms", "consistent_bias_arm", "consistent_coriolis_matrix_into", "consistent_forward_dynamics_into",
    "consistent_gravity_entries", "consistent_gravity_vector_into", "consistent_mass_entries",
    "consistent_mass_matrix_into", "consistent_qddot", "consistent_energies", "consistent_kinetic_energy",
    "consistent_potential_energy", "kinetic_energy", "potential_energy", "HELD_TAU", "INPUT_MAP_EXACT",
    "INPUT_MAP_PAPER", "generalized_forces", "generalized_forces_into", "generalized_forces_sc", "held_force",
    "thrust_body_forces", "thrust_curvature_work", "batch_jit", "inline", "accessor", "jit", "arm_offset",
    "paper_tip_positions_into", "tip_positions_into", "LANE_EXT", "LANE_P", "LANE_Q", "LANE_QD", "LANE_ROWS_RK4",
    "LANE_SC", "LANE_U", "LANES", "RK4_LANES", "lane_load", "lane_store", "rk4_lanes", "rk4_lanes_consistent",
    "rk4_lanes_partial", "coriolis_entries", "coriolis_entries_basis", "coriolis_matrix_into",
    "forward_dynamics_into", "gravity_entries", "gravity_entries_basis", "gravity_vector_into", "mass_entries",
    "mass_entries_basis", "mass_matrix_into", "qddot", "consistent_rk4_step", "consistent_rk4_step_into",
    "consistent_rk4_step_tuple", "consistent_stage", "rk4_step", "rk4_step_into", "rk4_step_sc", "rk4_step_tuple",
    "A_COEFFS", "C1_COEFFS", "D1P_COEFFS", "D2_COEFFS", "D2PQ_COEFFS", "HORNER_TERMS", "S0_COEFFS", "TWO_PI",
    "arm_basis", "horner", "one_minus_cos_over_q2", "rotate", "sin_cos", "sinc",
]
