"""The paper's model written symbolically for CasADi: what the MPC predicts with.

The compiled kernels of :mod:`softpvtol_gym.model` are the single source of truth of the physics, but
numba functions cannot take CasADi symbols. This module runs their own Python source on CasADi's symbols
(:func:`softpvtol_gym.model.twin.python_twin`: :mod:`softpvtol_gym.model.paper`'s ``qddot`` and
:mod:`softpvtol_gym.model.input_map`'s forces, the same curvature series, Horner's rule and Schur-complement
solve), and ``tests/control/test_mpc.py`` checks it against the kernels' public API
(:func:`softpvtol_gym.dynamics.forward_dynamics`, :func:`~softpvtol_gym.dynamics.generalized_forces`,
:func:`softpvtol_gym.integrators.rk4_step_actuated`) to ~1e-12 at random states. Only the paper's model
(the controllers' model in every tier) is written here.

State x = (q, qdot) (10): q = (x, z, theta, q_l, q_r); input u = (T_l, T_r, tau_l, tau_r) (4), held
over a step (zero-order hold, B(q) evaluated at every RK4 stage as in the env's physics step).
"""

from __future__ import annotations

import math

from ...model import input_map as input_map_kernels
from ...model import paper, series
from ...model.twin import python_twin
from ...params import P_LL, P_LR
from ._casadi import import_casadi

#: the input maps written here (:data:`softpvtol_gym.dynamics.INPUT_MAPS`)
INPUT_MAPS = ("paper", "exact")
#: |q_l|, |q_r| [rad] beyond which ``continuous_dynamics`` holds the curvature terms constant
CURVATURE_RANGE = 2.0 * math.pi


#: the model's own functions as plain Python (:func:`~softpvtol_gym.model.twin.python_twin`): the same equations,
#: the same operations in the same order, on CasADi's symbols
arm_basis = python_twin(series.arm_basis)
sin_cos_series = python_twin(series.sin_cos)
_qddot = python_twin(paper.qddot)
_generalized_forces_sc = python_twin(input_map_kernels.generalized_forces_sc)
_thrust_curvature_work = python_twin(input_map_kernels.thrust_curvature_work)


def qddot(q, qd, tau, p):
    """qddot = D(q)^-1 (tau - C(q, qdot) qdot - g(q)) of the paper's model, a list of 5 expressions
    (:func:`softpvtol_gym.model.paper.qddot`). q, qd, tau: indexable of 5; p: the parameter vector
    (``SoftPVTOLParams.array``)."""
    return list(_qddot(q[3], q[4], qd[3], qd[4], tau, p))


#: the size of the disturbance input d of :func:`continuous_dynamics`: a generalized force on each of x, z, theta,
#: q_l, q_r, and the share of each rotor's thrust that bends its arm (left, right)
DISTURBANCE_SIZE = 7


def thrust_bending(q, a, p):
    """The thrusts' work on the curvatures, (l_l T_l C1(q_l^2), l_r T_r C1(q_r^2)): the exact input map's arm
    rows less the paper's (:func:`softpvtol_gym.model.input_map.thrust_curvature_work`)."""
    return (_thrust_curvature_work(a[0], p[P_LL], q[3]), _thrust_curvature_work(a[1], p[P_LR], q[4]))


def generalized_forces(q, a, p, input_map: str):
    """tau = B(q) a for a = (T_l, T_r, tau_l, tau_r), a list of 5 expressions
    (:func:`softpvtol_gym.model.input_map.generalized_forces_sc`, sin and cos of theta by CasADi)."""
    if input_map not in INPUT_MAPS:
        raise ValueError(f"input_map must be one of {list(INPUT_MAPS)}, got {input_map!r}")
    ca = import_casadi()
    code = input_map_kernels.INPUT_MAP_PAPER if input_map == "paper" else input_map_kernels.INPUT_MAP_EXACT
    return list(_generalized_forces_sc(ca.sin(q[2]), ca.cos(q[2]), q[3], q[4], a, p, code))


def continuous_dynamics(p, input_map: str, disturbance: bool = False):
    """CasADi Function ``f(x[10], u[4]) -> xdot[10]`` of the paper's model with parameters p; with
    ``disturbance``, ``f(x[10], u[4], d[DISTURBANCE_SIZE])``: the MPC's estimate of the forces its model lacks,
    d[0:5] added to the generalized forces B(q) u, and d[5], d[6] the share of each rotor's thrust that bends its
    own arm (times :func:`thrust_bending`; 0: the paper's map, 1: the exact map's arm rows)."""
    ca = import_casadi()
    x = ca.SX.sym("x", 10)
    u = ca.SX.sym("u", 4)
    q, qd = [x[i] for i in range(5)], [x[5 + i] for i in range(5)]
    # the curvature terms are polynomials accurate to |q| = 2 pi (twice the env's limit) that grow without
    # bound beyond: there they are held at their values at +-2 pi, so that a rollout of the model that
    # leaves that range (an open-loop plan over the horizon) stays finite
    q[3], q[4] = (ca.fmin(ca.fmax(qi, -CURVATURE_RANGE), CURVATURE_RANGE) for qi in (q[3], q[4]))
    tau = generalized_forces(q, [u[i] for i in range(4)], p, input_map)
    inputs, names = [x, u], ["x", "u"]
    if disturbance:
        d = ca.SX.sym("d", DISTURBANCE_SIZE)
        tau = [tau[i] + d[i] for i in range(5)]
        bend_l, bend_r = thrust_bending(q, u, p)
        tau[3] = tau[3] + d[5] * bend_l
        tau[4] = tau[4] + d[6] * bend_r
        inputs.append(d)
        names.append("d")
    acc = qddot(q, qd, tau, p)
    return ca.Function("softpvtol_dynamics", inputs, [ca.vertcat(*qd, *acc)], names, ["xdot"])


def rk4_step(f, substeps: int = 1):
    """CasADi Function ``F(x[10], u[4], h) -> x_next[10]``: ``substeps`` classical RK4 steps of the
    continuous dynamics ``f`` over h seconds in all, u held. For an ``f`` with a disturbance input
    (``continuous_dynamics(..., disturbance=True)``): ``F(x, u, h, d[5])``, d held too."""
    ca = import_casadi()
    x = ca.SX.sym("x", 10)
    u = ca.SX.sym("u", 4)
    h = ca.SX.sym("h")
    extra = [ca.SX.sym("d", f.nnz_in(2))] if f.n_in() == 3 else []
    dt = h / substeps
    xn = x
    for _ in range(substeps):
        k1 = f(xn, u, *extra)
        k2 = f(xn + 0.5 * dt * k1, u, *extra)
        k3 = f(xn + 0.5 * dt * k2, u, *extra)
        k4 = f(xn + dt * k3, u, *extra)
        xn = xn + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    names = ["x", "u", "h"] + (["d"] if extra else [])
    return ca.Function("softpvtol_rk4", [x, u, h, *extra], [xn], names, ["x_next"])
