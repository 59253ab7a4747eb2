"""New episodes: initial state, reference parameters, plant parameters and noise key from a block of
uniforms that each env draws from its own RNG (one ``random(N_UNIFORMS)`` call per reset), so that an
env's episode depends only on its own generator."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._columns import Columns
from .._validation import bounded_number, real_array, short_repr
from ..params import PARAM_FIELDS
from ..references import N_REF_PARAMS, RP, RP_Z0
from ..tasks import HOVER_SETPOINT, PAPER_Q0, SAMPLE_CUSTOM, SAMPLE_HOVER, SAMPLE_PAPER, SAMPLE_SETPOINT
from .termination import BOX_X, BOX_Z, GROUND_Z, Q_LIMITS
from .tiers import MISMATCH_FIELDS

#: the plant parameters the mismatch tiers scale (their columns in the parameter vector)
_MISMATCH_COLUMNS = tuple(PARAM_FIELDS.index(f) for f in MISMATCH_FIELDS)
_N_MISMATCH = len(_MISMATCH_COLUMNS)
#: the uniforms each env draws from its RNG at every reset (a fixed number, whatever the task): the
#: initial-state perturbation (a registered task's ``initial_state`` gets them), the setpoint task's
#: set-point, track_random's sinusoids (x, then z), the plant mismatch (one per scaled parameter), spare
#: columns (drawn, unused) and the episode's noise key
UNIFORMS = Columns("reset_uniforms", [("state", 10), ("setpoint", 3), ("sinusoids", 18), ("mismatch", _N_MISMATCH),
                                      ("spare", 7), ("key", 2)])
U = UNIFORMS.at
N_UNIFORMS = UNIFORMS.size
N_STATE_UNIFORMS = UNIFORMS.widths["state"]
#: ``start_error_scale`` (an env argument and a reset option): its bound; ``start_distribution``'s values
MAX_START_ERROR_SCALE = 10.0
START_SCALE_REASON = ("x the task's starting deviation from the reference; at 10 the hover perturbation reaches "
                      "10 m and 3 rad, and positions are clipped into the start box")
START_DISTRIBUTIONS = ("task", "wide", "attitude")


def sample_episodes(cfg, u: np.ndarray, start_error_scale: float | None = None) -> dict[str, np.ndarray]:
    """Initial state q0, qd0 (N, 5), reference parameters refp (N, 21), plant parameters P (N, 10)
    and noise keys (N,) of len(u) new episodes, from uniforms u (N, N_UNIFORMS) in [0, 1).

    Columns of u: :data:`UNIFORMS` (0-9 initial state, 10-12 setpoint, 13-30 track_random reference,
    31-38 plant mismatch, 46-47 noise key). With c = 2 u - 1 in [-1, 1): the hover perturbation is
    dq = (c0, c1, 0.3 c2, 0.3 c3, 0.3 c4), dqd = (0.5 c5, 0.5 c6, 0.2 c7, 0.2 c8, 0.2 c9); hover starts
    at the setpoint + dq, setpoint at x = 3 c0, z = 2 + 2 c1 (setpoint x = 3 c10, z = 2 + 2 c11,
    theta = 0.3 c12), track_paper at the paper's q0 at rest, track_random at its reference + dq/2 (the
    reference: z0 = 3, amplitudes u*(1.0 | 0.5), rates 0.2 + 0.6 u, phases 2 pi u), a registered task
    at its reference at t = 0 + dq (or its own ``initial_state(u[:, :10])``); plant mismatch scales
    the masses, inertias and lengths by 1 + s c31..c38. ``cfg.start_distribution`` and the start-error
    scale (``start_error_scale``, by default ``cfg.start_error_scale``) then reshape the start
    (:func:`shape_starts`; nothing changes with "task" and scale 1).
    """
    n = u.shape[0]
    spec = cfg.task_spec
    refp = np.empty((n, N_REF_PARAMS))
    q0 = np.empty((n, 5))
    qd0 = np.empty((n, 5))
    P = np.empty((n, len(PARAM_FIELDS)))
    key = np.empty(n, dtype=np.uint64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    _sample_rows(u, spec.sampler, cfg.params.array, float(cfg.mismatch_scale), refp, q0, qd0, P, key)
    if spec.sampler == SAMPLE_CUSTOM and spec.initial_state is not None:
        q0, qd0 = _custom_initial_state(spec, u[:, :N_STATE_UNIFORMS])
    elif spec.sampler not in (SAMPLE_HOVER, SAMPLE_SETPOINT, SAMPLE_PAPER):
        # track_random and registered tasks: q0, qd0 hold the perturbation; add the reference at t = 0
        pos, vel, _ = spec.evaluate(np.zeros(n), refp)
        q0[:, :3] += pos
        qd0[:, :3] += vel
    scale = cfg.start_error_scale if start_error_scale is None else start_error_scale
    if cfg.start_distribution != "task" or scale != 1.0:
        q0, qd0 = shape_starts(cfg, u[:, U.state:U.state + N_STATE_UNIFORMS], refp, q0, qd0, float(scale))
    return dict(q0=q0, qd0=qd0, refp=refp, P=P, key=key)


#: ``start_distribution="wide"``: the half-widths of the uniform deviations from the reference at t = 0, on q
#: (x, z [m], theta, q_l, q_r [rad]; track_paper's start (5 m, -7 m, 0.63 rad, 0.03 rad, -0.47 rad) lies inside)
#: and on qdot [m/s, rad/s]
WIDE_Q = (6.0, 8.0, 0.7, 0.5, 0.5)
WIDE_QD = (1.0, 1.0, 0.5, 0.5, 0.5)
#: ``start_distribution="attitude"``: likewise, near the reference in position but turned, bent and spinning: the
#: states a controller has to recover from (the body up to 1.2 rad, turning at up to 2 rad/s)
ATTITUDE_Q = (1.0, 1.0, 1.2, 0.6, 0.6)
ATTITUDE_QD = (0.5, 0.5, 2.0, 1.0, 1.0)
#: the half-widths (on q, on qdot) of the start distributions that draw their deviations uniformly
START_HALF_WIDTHS = {"wide": (WIDE_Q, WIDE_QD), "attitude": (ATTITUDE_Q, ATTITUDE_QD)}
#: the box that reshaped starts are kept in: |x| <= START_X, START_Z_MIN <= z <= START_Z_MAX, |q_arm| <=
#: START_ARM (1 m inside the termination box, the ground limit 1 m below; the arms 0.1 pi inside the model's
#: validity)
START_X, START_Z_MIN, START_Z_MAX, START_ARM = BOX_X - 1.0, GROUND_Z + 1.0, BOX_Z - 1.0, 0.9 * math.pi


def shape_starts(cfg, u: np.ndarray, refp: np.ndarray, q0: np.ndarray, qd0: np.ndarray, scale: float):
    """Starting states (q0, qd0) (N, 5) reshaped by ``cfg.start_distribution`` and ``scale``, around the
    reference at t = 0 (q_ref(0) = (x_ref, z_ref, theta_ref, 0, 0), likewise qdot_ref(0)):

    * "task": q0 = q_ref(0) + scale (q0 - q_ref(0)), qd0 likewise; x, z and the arms then clipped into the
      start box (|x| <= 19 m, 0 <= z <= 19 m, |q_arm| <= 0.9 pi);
    * "wide": deviations scale x WIDE_Q c, scale x WIDE_QD c' from the episode's uniforms u (N, 10)
      (c = 2 u - 1); x and z uniform on the part of [ref - scale w, ref + scale w] inside the start box (a
      truncated uniform: no starts piled up on the box's edge), the arms clipped;
    * "attitude": the same with ATTITUDE_Q, ATTITUDE_QD (near the reference, turned and spinning).
    """
    n = u.shape[0]
    pos, vel, _ = cfg.task_spec.evaluate(np.zeros(n), refp)
    qr = np.zeros((n, 5))
    qdr = np.zeros((n, 5))
    qr[:, :3] = pos
    qdr[:, :3] = vel
    lo = np.array([-START_X, START_Z_MIN])
    hi = np.array([START_X, START_Z_MAX])
    if cfg.start_distribution in START_HALF_WIDTHS:
        wq, wqd = (np.asarray(w) for w in START_HALF_WIDTHS[cfg.start_distribution])
        c = 2.0 * u - 1.0
        q = qr + scale * wq * c[:, :5]
        qd = qdr + scale * wqd * c[:, 5:]
        a = np.maximum(qr[:, :2] - scale * wq[:2], lo)
        b = np.minimum(qr[:, :2] + scale * wq[:2], hi)
        q[:, :2] = np.where(a <= b, a + u[:, :2] * (b - a), np.clip(qr[:, :2], lo, hi))
    else:
        q = qr + scale * (q0 - qr)
        qd = qdr + scale * (qd0 - qdr)
    q[:, :2] = np.clip(q[:, :2], lo, hi)
    q[:, 3:] = np.clip(q[:, 3:], -START_ARM, START_ARM)
    return q, qd


def _custom_initial_state(spec, u):
    out = spec.initial_state(u.copy())
    n = u.shape[0]
    if not (isinstance(out, tuple) and len(out) == 2):
        raise ValueError(f"task {spec.name!r}: initial_state(u) must return (q0, qdot0), got {type(out)}")
    res = []
    for what, a in zip(("q0", "qdot0"), out):
        a = np.array(a, dtype=np.float64)
        if a.shape != (n, 5) or not np.isfinite(a).all():
            raise ValueError(f"task {spec.name!r}: initial_state(u) for u of shape {u.shape} must return a finite "
                             f"{what} of shape {(n, 5)}, got shape {a.shape}")
        res.append(a)
    return tuple(res)


@njit(cache=True, nogil=True, error_model="numpy")
def _sample_rows(u, sampler, params, scale, refp, q0, qd0, P, key):
    """The rows of :func:`sample_episodes` (``sampler``: the task's SAMPLE_* code; track_random:
    q0, qd0 get the halved perturbation, registered tasks the whole one; the caller adds the reference)."""
    two_pi = 2.0 * math.pi
    for i in range(u.shape[0]):
        s = U.state
        c0, c1, c2, c3, c4 = (2.0 * u[i, s] - 1.0, 2.0 * u[i, s + 1] - 1.0, 2.0 * u[i, s + 2] - 1.0,
                              2.0 * u[i, s + 3] - 1.0, 2.0 * u[i, s + 4] - 1.0)
        c5, c6, c7, c8, c9 = (2.0 * u[i, s + 5] - 1.0, 2.0 * u[i, s + 6] - 1.0, 2.0 * u[i, s + 7] - 1.0,
                              2.0 * u[i, s + 8] - 1.0, 2.0 * u[i, s + 9] - 1.0)
        dq = (c0 * 1.0, c1 * 1.0, c2 * 0.3, c3 * 0.3, c4 * 0.3)
        dqd = (c5 * 0.5, c6 * 0.5, c7 * 0.2, c8 * 0.2, c9 * 0.2)
        for k in range(N_REF_PARAMS):
            refp[i, k] = 0.0
        for k in range(5):
            q0[i, k] = dq[k]
            qd0[i, k] = dqd[k]
        if sampler == SAMPLE_HOVER:
            for k in range(3):
                refp[i, RP.setpoint + k] = HOVER_SETPOINT[k]
                q0[i, k] = HOVER_SETPOINT[k] + dq[k]
        elif sampler == SAMPLE_SETPOINT:
            refp[i, RP.setpoint] = 3.0 * (2.0 * u[i, U.setpoint] - 1.0)
            refp[i, RP.setpoint + 1] = 2.0 + 2.0 * (2.0 * u[i, U.setpoint + 1] - 1.0)
            refp[i, RP.setpoint + 2] = 0.3 * (2.0 * u[i, U.setpoint + 2] - 1.0)
            q0[i, 0] = 3.0 * c0
            q0[i, 1] = 2.0 + 2.0 * c1
        elif sampler == SAMPLE_PAPER:
            for k in range(5):
                q0[i, k] = PAPER_Q0[k]
                qd0[i, k] = 0.0
        elif sampler != SAMPLE_CUSTOM:  # track_random
            refp[i, RP_Z0] = 3.0
            for axis in range(2):  # x, then z: (a1, a2, a3, w1, w2, w3, phi1, phi2, phi3)
                amax = 1.0 if axis == 0 else 0.5
                b = RP.x_sinusoids if axis == 0 else RP.z_sinusoids
                o = U.sinusoids + 9 * axis
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
            for k in range(_N_MISMATCH):
                col = _MISMATCH_COLUMNS[k]
                P[i, col] = P[i, col] * (1.0 + scale * (2.0 * u[i, U.mismatch + k] - 1.0))
        key[i] = np.uint64(u[i, U.key] * 2.0**53) ^ (np.uint64(u[i, U.key + 1] * 2.0**53) << np.uint64(11))


#: the keys of ``reset(options=...)``: vectors, then the scalar "start_error_scale" (see EnvConfig)
RESET_OPTIONS = ("q0", "qdot0", "setpoint", "start_error_scale")
_OPTION_SIZES = {"q0": 5, "qdot0": 5, "setpoint": 3}


def _limits_text(name: str, lo: float, hi: float) -> str:
    if lo == -hi:
        return f"|{name}| <= {'pi' if hi == math.pi else f'{hi:g}'}"
    return f"{lo:g} <= {name} <= {hi:g}"


def check_reset_options(cfg, options, extra_keys: tuple = ()) -> dict:
    """``reset(options=...)`` checked before anything changes: a dict with keys from
    :data:`RESET_OPTIONS` (plus ``extra_keys``, the caller's: the vector env's ``reset_mask``), each
    None or a vector of real numbers: "q0" (5) inside the position limits of :mod:`.termination`
    (|x| <= 20 m, -1 <= z <= 20 m, |q_l|, |q_r| <= pi: the model's validity), "qdot0" (5) finite (a speed
    beyond the speed limits is a valid state: the episode ends as "out_of_bounds" at its first step),
    "setpoint" (3: x, z, theta; tasks with a constant reference) inside the box. Returns {key: float64
    array} of the options given."""
    valid = RESET_OPTIONS + tuple(extra_keys)
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ValueError(f"reset options must be a dict with keys from {list(valid)} (or None), got "
                         f"{short_repr(options)} of type {type(options).__name__}")
    unknown = [k for k in options if k not in valid]
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}; valid ones are {list(valid)}")
    out = {}
    if options.get("start_error_scale") is not None:
        out["start_error_scale"] = bounded_number("reset option 'start_error_scale'", options["start_error_scale"],
                                                  0.0, MAX_START_ERROR_SCALE, START_SCALE_REASON)
    for k in _OPTION_SIZES:
        if options.get(k) is None:
            continue
        size = _OPTION_SIZES[k]
        expected = f"{size} finite numbers" + (" (x, z, theta)" if k == "setpoint" else " (x, z, theta, q_l, q_r)"
                                                 if k == "q0" else " (xdot, zdot, thetadot, q_l dot, q_r dot)")
        v = real_array(f"reset option {k!r}", options[k], expected)
        if v.shape != (size,) or not np.isfinite(v).all():
            raise ValueError(f"reset option {k!r} must be {expected}, got {short_repr(options[k])}"
                             + (f" of shape {v.shape}" if v.shape != (size,) else ""))
        if k == "setpoint":
            if cfg.task_spec.sampler not in (SAMPLE_HOVER, SAMPLE_SETPOINT):
                raise ValueError(f"reset option 'setpoint' needs task 'hover' or 'setpoint' (a constant reference), "
                                 f"got task={cfg.task!r}")
            limits = (("x", -BOX_X, BOX_X, "out_of_bounds"), ("z", GROUND_Z, BOX_Z, "ground/out_of_bounds"))
        else:
            limits = Q_LIMITS if k == "q0" else ()
        for i, (name, lo, hi, reason) in enumerate(limits):
            if not (lo <= v[i] <= hi):
                why = ("a target outside the termination box cannot be reached" if k == "setpoint" else
                       f"the env's valid states; beyond it the episode ends at once: {reason}")
                raise ValueError(
                    f"reset option {k!r}[{i}] ({name}) = {float(v[i])!r} is outside {_limits_text(name, lo, hi)} "
                    f"({why}); give a value inside the limits of softpvtol_gym.envs.termination"
                )
        out[k] = v
    return out


def apply_options(cfg, ep: dict, options: dict) -> dict:
    """reset(options=...) (checked by :func:`check_reset_options`) written into the episodes ``ep``."""
    for k, v in check_reset_options(cfg, options).items():
        if k == "start_error_scale":  # (used by sample_episodes)
            continue
        if k == "setpoint":
            ep["refp"][:, RP.setpoint:RP.setpoint + 3] = v
        else:
            ep["q0" if k == "q0" else "qd0"][:] = v
    return ep
