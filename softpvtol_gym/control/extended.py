"""The dynamically extended loop on (x, z, theta, sigma = q_l + q_r) (docs/control.md).

The paper's model, actuators a = (T_l, T_r, tau_l, tau_r). The arm torques are used by computed torque
to give the arms any accelerations w = (w_l, w_r); the total thrust T = T_l + T_r is a state of the
controller (the dynamic extension: T and Tdot are its memory, Tddot = u_1 its input); the thrust split
is fixed by the attitude loop. The outputs:

* sigma = q_l + q_r, regulated to 0: sigma'' = w_l + w_r (relative degree 2);
* theta: theta'' = tau_theta(q_a, T_l, T_r) / I (relative degree 2), which fixes T_l - T_r;
* the centre of mass y = p + psi(q_a) of the paper's Lagrangian (body and rotor masses):
  M y'' = R(theta) (T_l u_l(q_l) + T_r u_r(q_r)) - (0, M g) carries no arm acceleration, so with the
  thrust extension y'''' is affine in (u_1, w_l - w_r) with the invertible decoupling matrix
  R(theta) [A, T A_delta + v B_delta] (T > 0; see ``docs/control.md``): relative degrees 4, 4, 2, 2,
  12 = 10 states + 2 extension states, no zero dynamics.

Why the centre of mass and not the body point p: with equal arms psi(q_a) = 0 wherever sigma = 0 (the
rotor centroid is the body point), so y = p on the invariant set sigma = sigmadot = 0, where the body
point itself has relative degree 4. Off it, p'' contains D_ba (1, -1)^T (w_l - w_r) / 2 / M, which is
O(sigma): the body point has no vector relative degree near sigma = 0 (tests/control/test_extended_loop_derivation.py
shows the decoupling matrix). The centre of mass has one everywhere, and p - y = -psi(q_a) = O(sigma)
decays with the exactly linear sigma loop, so the body position error converges to round-off.

Plain numpy, batched over a leading axis; D, C, g and B(q) come from :mod:`softpvtol_gym.dynamics`
(the model kernels); only the derivatives of the thrust map are written here (checked against sympy
and finite differences in the tests).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable

import numpy as np

from .._series_coefficients import COEFFICIENTS
from ..dynamics import (
    arm_tip_positions,
    coriolis_matrix,
    forward_dynamics,
    generalized_forces,
    gravity_vector,
    input_map_code,
    mass_matrix,
)
from ..integrators import rk4_step_actuated, rk4_step_of_rates
from ..params import SoftPVTOLParams
from .references import paper_reference

__all__ = ["ExtendedGains", "ExtendedOutput", "ExtendedController", "simulate_extended_loop", "hurwitz",
           "HELD_COMMANDS"]

#: how a command held over a step is chosen (:meth:`ExtendedController.held_step`)
HELD_COMMANDS = ("midpoint", "start")


def hurwitz(coefficients) -> bool:
    """True if s^n + c_{n-1} s^{n-1} + ... + c_0 (``coefficients`` = (c_0, ..., c_{n-1}), n = 2 or 4) is
    Hurwitz (Routh-Hurwitz)."""
    c = [float(x) for x in coefficients]
    if not all(math.isfinite(x) and x > 0 for x in c):
        return False
    if len(c) == 2:
        return True
    c0, c1, c2, c3 = c
    return c3 * c2 > c1 and c3 * c2 * c1 > c1 * c1 + c3 * c3 * c0


@dataclasses.dataclass(frozen=True)
class ExtendedGains:
    """Linear error dynamics of the extended loop (coefficients low order first).

    ``position`` (k0, k1, k2, k3): e'''' + k3 e''' + k2 e'' + k1 e' + k0 e = 0 for the centre of mass
    (x and z); default (s + 1)^4. ``attitude`` (k0, k1): e'' + k1 e' + k0 e = 0 for theta; default
    (s + 2)^2. ``sigma`` (k0, k1): the same for sigma = q_l + q_r; default (s + 5)^2. Each polynomial
    must be Hurwitz (ValueError otherwise).
    """

    position: tuple[float, float, float, float] = (1.0, 4.0, 6.0, 4.0)
    attitude: tuple[float, float] = (4.0, 4.0)
    sigma: tuple[float, float] = (25.0, 10.0)

    def __post_init__(self) -> None:
        for name, n in (("position", 4), ("attitude", 2), ("sigma", 2)):
            value = getattr(self, name)
            try:
                c = tuple(float(x) for x in value)
            except (TypeError, ValueError):
                raise ValueError(f"ExtendedGains.{name} must be {n} real numbers, got {value!r}") from None
            if len(c) != n or not hurwitz(c):
                raise ValueError(f"ExtendedGains.{name} must be the {n} coefficients (low order first) of a Hurwitz "
                                 f"polynomial s^{n} + ... (stable error dynamics), got {value!r}")
            object.__setattr__(self, name, c)


@dataclasses.dataclass
class ExtendedOutput:
    """One evaluation of the extended loop. Shapes: batch + (k,).

    actuators: (T_l, T_r, tau_l, tau_r) to apply through ``generalized_forces``; tau: their generalized
    force B(q) a (5); thrust_state: the extension (T, Tdot) used; thrust_accel: its input Tddot = u_1;
    arm_acceleration: (w_l, w_r) asked of the arms; outputs: (y_x, y_z, theta, sigma), y the centre of
    mass; degenerate: True where the decoupling could not be inverted as is (T below ``min_thrust`` or
    |h_l + h_r| below ``min_torque_arm``) and the safeguarded values were used; output_derivatives:
    (y, y', y'', y''', y'''') of the centre of mass (5, 2), y'''' as the loop assigns it.
    """

    actuators: np.ndarray
    tau: np.ndarray
    thrust_state: np.ndarray
    thrust_accel: np.ndarray
    arm_acceleration: np.ndarray
    outputs: np.ndarray
    output_derivatives: np.ndarray
    degenerate: np.ndarray


def _horner(c, s):
    acc = np.full_like(s, c[-1])
    for k in range(len(c) - 2, -1, -1):
        acc = acc * s + c[k]
    return acc


def sinc_derivatives(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sinc, sinc', sinc'') of x, sinc x = sin x / x: the package's series for |x| < 1, closed forms beyond."""
    x = np.asarray(x, dtype=np.float64)
    s = x * x
    small = np.abs(x) < 1.0
    f0s = _horner(COEFFICIENTS["S0"], s)
    f1s = -x * _horner(COEFFICIENTS["A"], s)  # sinc' = -D1 = -q A(q^2)
    f2s = -_horner(COEFFICIENTS["D1p"], s)  # sinc'' = -dD1/dq
    xs = np.where(small, 1.0, x)
    sn, cs = np.sin(xs), np.cos(xs)
    f0c = sn / xs
    f1c = (xs * cs - sn) / (xs * xs)
    f2c = ((2.0 - xs * xs) * sn - 2.0 * xs * cs) / (xs * xs * xs)
    return np.where(small, f0s, f0c), np.where(small, f1s, f1c), np.where(small, f2s, f2c)


def torque_arm(q: np.ndarray, length: float, eps: float, input_map: str) -> tuple[np.ndarray, ...]:
    """(h, h', h'') of a rotor's moment arm h(q): tau_theta = h(q_r) T_r - h(q_l) T_l.

    ``"paper"`` map: h = l cos q sinc q = l sinc(2 q); ``"exact"``: h = eps cos q + l sinc q."""
    if input_map == "paper":
        f0, f1, f2 = sinc_derivatives(2.0 * q)
        return length * f0, 2.0 * length * f1, 4.0 * length * f2
    f0, f1, f2 = sinc_derivatives(q)
    c, s = np.cos(q), np.sin(q)
    return eps * c + length * f0, -eps * s + length * f1, -eps * c + length * f2


def _quotient(N, Nl, Nr, Nll, Nlr, Nrr, H, Hl, Hr, Hll, Hrr):
    """X = N / H and its first and second partials in (q_l, q_r) (H_lr = 0); N's are (2, n), H's (n,)."""
    X = N / H
    Xl = (Nl - X * Hl) / H
    Xr = (Nr - X * Hr) / H
    Xll = (Nll - 2.0 * Xl * Hl - X * Hll) / H
    Xrr = (Nrr - 2.0 * Xr * Hr - X * Hrr) / H
    Xlr = (Nlr - Xl * Hr - Xr * Hl) / H
    return X, Xl, Xr, Xll, Xlr, Xrr


def _rot(c, s, v):
    """R(theta) v for v (2, n)."""
    return np.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _rot_j(c, s, v):
    """R(theta) J v, J = [[0, -1], [1, 0]] (dR/dtheta = R J)."""
    return _rot(c, s, np.stack([-v[1], v[0]]))


class ExtendedController:
    """The dynamically extended feedback linearisation on (y_x, y_z, theta, sigma) (module docstring).

    Args:
        params: model parameters the controller believes (the paper's model); the arms must be equal
            (m_l = m_r, l_l = l_r), else the rotor centroid is not the body point at sigma = 0 (ValueError).
        gains: :class:`ExtendedGains`.
        input_map: the plant's input map ("paper" or "exact"; the paper's model).
        dt: control period [s]: :meth:`__call__` advances the extension (T, Tdot) over it with the
            Tddot it computed (exact for a held Tddot).
        min_thrust: the decoupling divides by T; below this [N] (default 5 % of the hover thrust M g)
            it uses ``min_thrust`` instead and reports ``degenerate``.
        initial_thrust: T at a reset [N]; None: M |p_ref'' + (0, g)|, the thrust the reference needs.
        held_command: what :meth:`__call__` returns to be held over dt (:meth:`held_step`): "midpoint"
            (default), the law at the step's predicted midpoint (a tracking error O(dt^2) when the
            reference there is known); "start", the law at the step's start (O(dt)).

    The memory is the extension (T, Tdot) per batch entry, created at the first call and reset by
    :meth:`reset` (all or a mask): ``ExtendedPolicy`` resets it at ``episode_start``.
    """

    loop = "extended"

    def __init__(self, params: SoftPVTOLParams | None = None, gains: ExtendedGains | None = None,
                 input_map: str = "paper", dt: float = 0.01, min_thrust: float | None = None,
                 initial_thrust: float | None = None, held_command: str = "midpoint") -> None:
        self.params = SoftPVTOLParams() if params is None else params
        if not isinstance(self.params, SoftPVTOLParams):
            raise ValueError(f"params must be a SoftPVTOLParams, got {type(params).__name__}")
        p = self.params
        if p.m_l != p.m_r or p.l_l != p.l_r:
            raise ValueError(
                f"the extended loop needs equal arms (m_l = m_r and l_l = l_r: then the rotor centroid is the body "
                f"point when q_l + q_r = 0), got m_l={p.m_l}, m_r={p.m_r}, l_l={p.l_l}, l_r={p.l_r}")
        if gains is not None and not isinstance(gains, ExtendedGains):
            raise ValueError(f"gains must be an ExtendedGains or None for the extended loop, got "
                             f"{type(gains).__name__}")
        self.gains = ExtendedGains() if gains is None else gains
        input_map_code(input_map)
        self.input_map = input_map
        if not (isinstance(dt, (int, float)) and not isinstance(dt, bool) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0 [s], got {dt!r}")
        self.dt = float(dt)
        hover = p.total_mass * p.g
        if min_thrust is None:
            min_thrust = 0.05 * hover if hover > 0 else 1e-3
        if not (isinstance(min_thrust, (int, float)) and math.isfinite(min_thrust) and min_thrust > 0):
            raise ValueError(f"min_thrust must be a finite number > 0 [N], got {min_thrust!r}")
        self.min_thrust = float(min_thrust)
        if initial_thrust is not None and not (isinstance(initial_thrust, (int, float)) and
                                               math.isfinite(initial_thrust) and initial_thrust > 0):
            raise ValueError(f"initial_thrust must be None or a finite number > 0 [N], got {initial_thrust!r}")
        self.initial_thrust = initial_thrust
        if held_command not in HELD_COMMANDS:
            raise ValueError(f"held_command must be one of {HELD_COMMANDS}, got {held_command!r}")
        self.held_command = held_command
        #: the smallest |h_l + h_r| [m] the thrust split divides by (the rotors' moment arms vanish at |q| = pi/2
        #: with the paper's map)
        self.min_torque_arm = 1e-3 * p.l_l
        self._xi: np.ndarray | None = None

    # ------------------------------------------------------------------------------------ memory
    def reset(self, mask=None) -> None:
        """Forget the extension (all entries, or those where ``mask``): re-initialised at the next call."""
        if mask is None or self._xi is None:
            self._xi = None
            return
        self._xi[np.asarray(mask, dtype=bool).reshape(-1)] = np.nan

    @property
    def thrust_state(self) -> np.ndarray | None:
        """The extension (T, Tdot) per batch entry (n, 2), or None before the first call."""
        return self._xi

    def initial_extension(self, qddot_ref: np.ndarray) -> np.ndarray:
        """(T, Tdot) at a reset, (n, 2): ``initial_thrust`` or M |p_ref'' + (0, g)|, and Tdot = 0."""
        p = self.params
        n = qddot_ref.shape[0]
        xi = np.zeros((n, 2))
        if self.initial_thrust is not None:
            xi[:, 0] = self.initial_thrust
        else:
            xi[:, 0] = p.total_mass * np.hypot(qddot_ref[:, 0], qddot_ref[:, 1] + p.g)
        xi[:, 0] = np.maximum(xi[:, 0], self.min_thrust)
        return xi

    # ------------------------------------------------------------------------------------ the law
    def evaluate(self, q, qdot, xi, ref) -> ExtendedOutput:
        """The control law, pure: state q, qdot (n, 5), extension xi = (T, Tdot) (n, 2), reference
        ``ref`` (5, n, 5): q_ref and its first four time derivatives (body entries x, z, theta used;
        sigma's reference is 0)."""
        p = self.params
        gp, ga, gs = self.gains.position, self.gains.attitude, self.gains.sigma
        q = np.asarray(q, dtype=np.float64)
        qd = np.asarray(qdot, dtype=np.float64)
        n = q.shape[0]
        M, inertia, ll, eps = p.total_mass, p.I, p.l_l, p.epsilon
        th, ql, qr = q[:, 2], q[:, 3], q[:, 4]
        thd, vl, vr = qd[:, 2], qd[:, 3], qd[:, 4]
        T_raw, Td = xi[:, 0], xi[:, 1]
        # attitude loop: theta'' = v exactly (I theta'' = tau_theta in the paper's model)
        e0, e1 = th - ref[0][:, 2], thd - ref[1][:, 2]
        v = ref[2][:, 2] - ga[1] * e1 - ga[0] * e0
        vd = ref[3][:, 2] - ga[1] * (v - ref[2][:, 2]) - ga[0] * e1
        vdd = ref[4][:, 2] - ga[1] * (vd - ref[3][:, 2]) - ga[0] * (v - ref[2][:, 2])
        # sigma loop: sigma'' = w_l + w_r = vs
        vs = -gs[1] * (vl + vr) - gs[0] * (ql + qr)
        # thrust map: V = T_l u_l + T_r u_r = T A(q_a) + v B(q_a) with the split that gives tau_theta = I v
        hl, hl1, hl2 = torque_arm(ql, ll, eps, self.input_map)
        hr, hr1, hr2 = torque_arm(qr, ll, eps, self.input_map)
        H = hl + hr
        small_h = np.abs(H) < self.min_torque_arm
        H = np.where(small_h, np.where(H < 0, -1.0, 1.0) * self.min_torque_arm, H)
        sl, cl, sr, cr = np.sin(ql), np.cos(ql), np.sin(qr), np.cos(qr)
        ul, ul1 = np.stack([sl, cl]), np.stack([cl, -sl])
        ur, ur1 = np.stack([-sr, cr]), np.stack([-cr, -sr])
        ul2, ur2 = -ul, -ur
        A, Al, Ar, All, Alr, Arr = _quotient(
            hr * ul + hl * ur, hr * ul1 + hl1 * ur, hr1 * ul + hl * ur1,
            hr * ul2 + hl2 * ur, hr1 * ul1 + hl1 * ur1, hr2 * ul + hl * ur2, H, hl1, hr1, hl2, hr2)
        B, Bl, Br, Bll, Blr, Brr = _quotient(
            inertia * (ur - ul), -inertia * ul1, inertia * ur1, -inertia * ul2, np.zeros_like(ul), inertia * ur2,
            H, hl1, hr1, hl2, hr2)
        small_t = T_raw < self.min_thrust
        T = np.where(small_t, self.min_thrust, T_raw)
        V = T * A + v * B
        Aq, Bq = Al * vl + Ar * vr, Bl * vl + Br * vr
        Aqq = All * vl * vl + 2.0 * Alr * vl * vr + Arr * vr * vr
        Bqq = Bll * vl * vl + 2.0 * Blr * vl * vr + Brr * vr * vr
        Vd = Td * A + T * Aq + vd * B + v * Bq
        w0 = 0.5 * vs  # arm accelerations with w_l - w_r = 0
        Vdd0 = 2.0 * Td * Aq + T * (Aqq + (Al + Ar) * w0) + vdd * B + 2.0 * vd * Bq + v * (Bqq + (Bl + Br) * w0)
        G = 0.5 * (T * (Al - Ar) + v * (Bl - Br))  # d V'' / d (w_l - w_r)
        c, s = np.cos(th), np.sin(th)
        Phi = _rot(c, s, V)
        Phi[1] -= M * p.g
        Phid = thd * _rot_j(c, s, V) + _rot(c, s, Vd)
        Phidd0 = -thd * thd * _rot(c, s, V) + v * _rot_j(c, s, V) + 2.0 * thd * _rot_j(c, s, Vd) + _rot(c, s, Vdd0)
        # outputs: the centre of mass y = p + psi(q_a) and ydot = pdot + D_ba qdot_a / M
        D = mass_matrix(q, p)
        tips = arm_tip_positions(q, p, model="paper")
        y = q[:, 0:2] + (p.m_l * (tips[:, 0] - q[:, 0:2]) + p.m_r * (tips[:, 1] - q[:, 0:2])) / M
        yd = qd[:, 0:2] + np.einsum("nij,nj->ni", D[:, 0:2, 3:5], qd[:, 3:5]) / M
        ydd, yddd = Phi.T / M, Phid.T / M
        r = [ref[k][:, 0:2] for k in range(5)]
        y4 = r[4] - gp[3] * (yddd - r[3]) - gp[2] * (ydd - r[2]) - gp[1] * (yd - r[1]) - gp[0] * (y - r[0])
        # R [A, G] (u1, w_delta) = M y4 - Phidd0
        rhs = M * y4.T - Phidd0
        rhs = np.stack([c * rhs[0] + s * rhs[1], -s * rhs[0] + c * rhs[1]])  # R^T
        det = A[0] * G[1] - A[1] * G[0]
        u1 = (rhs[0] * G[1] - rhs[1] * G[0]) / det
        wdel = (A[0] * rhs[1] - A[1] * rhs[0]) / det
        wl, wr = w0 + 0.5 * wdel, w0 - 0.5 * wdel
        # thrusts from the extension state (T_l + T_r = T, h_r T_r - h_l T_l = I v)
        Tl = (T_raw * hr - inertia * v) / H
        Tr = (T_raw * hl + inertia * v) / H
        # arm torques by computed torque: the arms accelerate at (w_l, w_r)
        Fth = generalized_forces(q, np.stack([Tl, Tr, np.zeros(n), np.zeros(n)], axis=-1), p, self.input_map)
        Cq = np.einsum("nij,nj->ni", coriolis_matrix(q, qd, p), qd)
        g = gravity_vector(q, p)
        w = np.stack([wl, wr], axis=-1)
        pdd = (Fth[:, 0:2] - np.einsum("nij,nj->ni", D[:, 0:2, 3:5], w) - Cq[:, 0:2] - g[:, 0:2]) / M
        tau_arm = (np.einsum("nij,nj->ni", D[:, 3:5, 0:2], pdd) + np.einsum("nij,nj->ni", D[:, 3:5, 3:5], w)
                   + Cq[:, 3:5] + g[:, 3:5] - Fth[:, 3:5])
        act = np.stack([Tl, Tr, tau_arm[:, 0], tau_arm[:, 1]], axis=-1)
        tau = generalized_forces(q, act, p, self.input_map)
        outputs = np.stack([y[:, 0], y[:, 1], th, ql + qr], axis=-1)
        return ExtendedOutput(actuators=act, tau=tau, thrust_state=np.stack([T_raw, Td], axis=-1), thrust_accel=u1,
                              arm_acceleration=w, outputs=outputs,
                              output_derivatives=np.stack([y, yd, ydd, yddd, y4], axis=1),
                              degenerate=small_t | small_h)

    # ------------------------------------------------------------------------------------ the step
    def held_step(self, q, qdot, xi, ref, dt: float | None = None,
                  ref_mid: np.ndarray | None = None) -> tuple[ExtendedOutput, np.ndarray]:
        """The command to hold over a step of ``dt`` (default: the controller's) from the state, the
        extension xi (n, 2) and the reference jet ``ref`` (5, n, 5) at the step's start, and the extension
        at the step's end. ``held_command="start"``: the law there, the extension advanced with its Tddot
        (exact for a held Tddot); the held command lags the continuous law by O(dt). ``"midpoint"``: the
        law at the step's predicted midpoint (the state advanced by dt/2 under the start's command with
        the controller's model, the extension and the reference by their Taylor series), the extension
        advanced with the midpoint's Tddot: the held command is the continuous law's average over the
        step to O(dt^2) when the reference there is known (``ref_mid``, the jet at the step's midpoint;
        without it the jet is extrapolated by its Taylor series, whose fourth derivative is then off by
        dt/2 times the fifth)."""
        h = self.dt if dt is None else float(dt)
        out = self.evaluate(q, qdot, xi, ref)
        if self.held_command == "midpoint":
            m = 0.5 * h
            qm, vm = rk4_step_actuated(q, qdot, out.actuators, self.params, m, self.input_map)
            u0 = out.thrust_accel
            xim = np.stack([xi[:, 0] + m * xi[:, 1] + 0.5 * m * m * u0, xi[:, 1] + m * u0], axis=-1)
            fact = (1.0, m, m * m / 2.0, m**3 / 6.0, m**4 / 24.0)
            refm = ref_mid if ref_mid is not None else np.stack(
                [sum(fact[j] * ref[i + j] for j in range(5 - i)) for i in range(5)])
            # a row whose predicted midpoint leaves the model's range (a diverging episode: arms predicted past
            # pi, or non-finite) holds the start's command instead
            bad = ~(np.isfinite(qm).all(-1) & np.isfinite(vm).all(-1) & (np.abs(qm[..., 3:5]) <= math.pi).all(-1))
            if bad.any():
                qm, vm, xim = np.where(bad[:, None], q, qm), np.where(bad[:, None], qdot, vm), np.where(
                    bad[:, None], xi, xim)
                refm = np.where(bad[None, :, None], ref, refm)
            out = self.evaluate(qm, vm, xim, refm)
        u1 = out.thrust_accel
        return out, np.stack([xi[:, 0] + h * xi[:, 1] + 0.5 * h * h * u1, xi[:, 1] + h * u1], axis=-1)

    def __call__(self, q, qdot, q_ref, qdot_ref, qddot_ref, q3_ref=None, q4_ref=None,
                 commit: bool = True, ref_mid: np.ndarray | None = None) -> ExtendedOutput:
        """One control step, the command to hold over ``dt`` (:meth:`held_step`, from the memory's
        extension, which then advances to the step's end; ``commit=False``: the memory is kept). The
        reference's third and fourth derivatives ``q3_ref``, ``q4_ref`` default to zero (a reference whose
        acceleration is constant); ``ref_mid`` (5, n, 5): the reference jet at the step's midpoint, if
        known (:meth:`held_step`)."""
        arrays = [q, qdot, q_ref, qdot_ref, qddot_ref,
                  np.zeros(5) if q3_ref is None else q3_ref, np.zeros(5) if q4_ref is None else q4_ref]
        names = ("q", "qdot", "q_ref", "qdot_ref", "qddot_ref", "q3_ref", "q4_ref")
        arrs = []
        for name, a in zip(names, arrays):
            a = np.asarray(a, dtype=np.float64)
            if a.ndim == 0 or a.shape[-1] != 5:
                raise ValueError(f"{name} must have shape (5,) or (..., 5), got shape {a.shape}")
            arrs.append(a)
        try:
            shape = np.broadcast_shapes(*(a.shape for a in arrs))
        except ValueError:
            raise ValueError(f"q, qdot and the references must broadcast, got shapes "
                             f"{[a.shape for a in arrs]}") from None
        flat = [np.broadcast_to(a, shape).reshape(-1, 5) for a in arrs]
        for name, a in zip(names, flat):
            if not np.isfinite(a).all():
                raise ValueError(f"{name} contains NaN or inf; the extended loop needs finite states and references")
        n = flat[0].shape[0]
        if self._xi is None:
            self._xi = np.full((n, 2), np.nan)
        elif self._xi.shape[0] != n:
            raise ValueError(f"the controller's memory is for a batch of {self._xi.shape[0]} entries, got {n}; "
                             "call reset() before changing the batch size")
        fresh = np.isnan(self._xi[:, 0])
        xi = self._xi.copy()
        if fresh.any():
            xi[fresh] = self.initial_extension(flat[4][fresh])
        if ref_mid is not None:
            ref_mid = np.asarray(ref_mid, dtype=np.float64).reshape(5, n, 5)
        out, xi_next = self.held_step(flat[0], flat[1], xi, np.stack(flat[2:]), ref_mid=ref_mid)
        if commit:
            self._xi = xi_next
        lead = shape[:-1]
        if lead != (n,):
            out = ExtendedOutput(**{f.name: getattr(out, f.name).reshape(lead + getattr(out, f.name).shape[1:])
                                    for f in dataclasses.fields(out)})
        return out


def reference_jet(reference: Callable, t) -> tuple[np.ndarray, ...]:
    """q_ref and its first four derivatives (5 arrays (..., 5)) from ``reference(t, order=4)``."""
    try:
        accepts = "order" in inspect.signature(reference).parameters
    except (TypeError, ValueError):
        accepts = False
    if not accepts:
        raise ValueError("the extended loop needs the reference's third and fourth derivatives: pass a reference "
                         "callable reference(t, order=4) -> (q, qdot, qddot, q3, q4), like "
                         f"control.paper_reference; got {reference!r}")
    jet = reference(t, order=4)
    if len(jet) != 5:
        raise ValueError(f"reference(t, order=4) must return 5 arrays (q_ref and 4 derivatives), got {len(jet)}")
    return tuple(np.asarray(j, dtype=np.float64) for j in jet)


def simulate_extended_loop(
    *,
    params: SoftPVTOLParams | None = None,
    gains: ExtendedGains | None = None,
    q0=(5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi),
    qdot0=(0.0, 0.0, 0.0, 0.0, 0.0),
    reference: Callable = paper_reference,
    t_final: float = 40.0,
    dt: float = 0.01,
    input_map: str = "paper",
    plant_params: SoftPVTOLParams | None = None,
    hold: str = "stage",
    initial_thrust: float | None = None,
    held_command: str = "midpoint",
) -> dict[str, np.ndarray]:
    """``simulate_closed_loop("extended", ...)``: the extended loop with fixed-step RK4.

    ``hold="stage"``: the controller at every RK4 stage, the extension (T, Tdot) integrated with the plant
    (the continuous-time closed loop). ``hold="step"``: the actuators of
    :meth:`ExtendedController.held_step` (``held_command``: "midpoint", the default, with the reference's
    jet at each step's midpoint, or "start") held over
    each step (B(q) at every stage), as the env's policy holds them. Returns the keys of :func:`simulate_closed_loop`
    (``arm_reference`` and ``storage`` NaN: this loop has neither; the algebraic-loop entries 0) plus
    ``thrust_state`` (T+1, 2), ``outputs`` (T, 4: y_x, y_z, theta, sigma at each step's start) and
    ``degenerate`` (T,: steps where the decoupling was safeguarded). ``q0``, ``qdot0`` of shape (k, 5)
    simulate k starts at once (every series gains an axis of k after the time axis).
    """
    if hold not in ("stage", "step"):
        raise ValueError(f"hold must be one of ('stage', 'step'), got {hold!r}")
    params = SoftPVTOLParams() if params is None else params
    plant = params if plant_params is None else plant_params
    ctrl = ExtendedController(params, gains, input_map=input_map, dt=dt, initial_thrust=initial_thrust,
                              held_command=held_command)
    n = int(round(t_final / dt))
    t = np.arange(n + 1) * dt
    jet_all = reference_jet(reference, t)
    q_ref_all, qd_ref_all = (np.array(np.broadcast_to(r, (n + 1, 5))) for r in jet_all[:2])
    q0, qdot0 = np.asarray(q0, dtype=np.float64), np.asarray(qdot0, dtype=np.float64)
    batched = q0.ndim == 2
    q, v = np.broadcast_arrays(np.atleast_2d(q0), np.atleast_2d(qdot0))
    q, v = q.copy(), v.copy()
    if q.ndim != 2 or q.shape[1] != 5:
        raise ValueError(f"q0 and qdot0 must have shape (5,) or (k, 5), got {q0.shape} and {qdot0.shape}")
    k_runs = q.shape[0]
    xi = ctrl.initial_extension(np.broadcast_to(np.broadcast_to(jet_all[2], (n + 1, 5))[0], (k_runs, 5)))
    Q, V, XI = np.empty((n + 1, k_runs, 5)), np.empty((n + 1, k_runs, 5)), np.empty((n + 1, k_runs, 2))
    tau_app, act = np.empty((n, k_runs, 5)), np.empty((n, k_runs, 4))
    outs, degen = np.empty((n, k_runs, 4)), np.zeros((n, k_runs), dtype=bool)
    Q[0], V[0], XI[0] = q, v, xi

    def law(tk, qk, vk, xk):
        jet = np.stack([np.broadcast_to(j, (k_runs, 5)) for j in reference_jet(reference, tk)])
        out = ctrl.evaluate(qk, vk, xk, jet)
        tau = generalized_forces(qk, out.actuators, plant, input_map)
        return forward_dynamics(qk, vk, tau, plant), np.stack([xk[:, 1], out.thrust_accel], axis=-1), out, tau

    for k in range(n):
        tk = t[k]
        if hold == "step":  # the command of ExtendedController.held_step, as the env's policy holds it
            jet = np.stack([np.broadcast_to(j, (k_runs, 5)) for j in reference_jet(reference, tk)])
            jet_mid = np.stack([np.broadcast_to(j, (k_runs, 5)) for j in reference_jet(reference, tk + 0.5 * dt)])
            out, xi_next = ctrl.held_step(q, v, xi, jet, ref_mid=jet_mid)
            tau = generalized_forces(q, out.actuators, plant, input_map)
            act[k], tau_app[k], outs[k], degen[k] = out.actuators, tau, out.outputs, out.degenerate
            q, v = rk4_step_actuated(q, v, out.actuators, plant, dt, input_map)
            xi = xi_next
        else:
            a1, x1, out, tau = law(tk, q, v, xi)
            act[k], tau_app[k], outs[k], degen[k] = out.actuators, tau, out.outputs, out.degenerate
            q, v, xi = rk4_step_of_rates(lambda ts, qs, vs, xs: law(ts, qs, vs, xs)[:2], tk, q, v, dt, (a1, x1), xi)
        Q[k + 1], V[k + 1], XI[k + 1] = q, v, xi
    if not batched:
        Q, V, XI, tau_app, act, outs, degen = (a[:, 0] for a in (Q, V, XI, tau_app, act, outs, degen))
    lead = Q.shape[1:-1]
    return dict(
        t=t, q=Q, qdot=V, q_ref=q_ref_all, qdot_ref=qd_ref_all, tau=tau_app.copy(), tau_applied=tau_app,
        actuators=act, arm_reference=np.full((n,) + lead + (2,), np.nan), allocation_residual=np.zeros((n,) + lead),
        algebraic_residual=np.zeros((n,) + lead), algebraic_iterations=np.zeros((n,) + lead, dtype=np.int64),
        storage=np.full((n + 1,) + lead, np.nan), thrust_state=XI, outputs=outs, degenerate=degen,
    )
