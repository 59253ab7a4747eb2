"""Physical parameters of the Soft-PVTOL (paper, Sec. 2 and Sec. 4)."""

from __future__ import annotations

import dataclasses
import math
from functools import cached_property

import numpy as np

#: Order of the fields in :attr:`SoftPVTOLParams.array`, the flat float64 vector the kernels take.
PARAM_FIELDS: tuple[str, ...] = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r", "g", "epsilon")
#: length of :attr:`SoftPVTOLParams.array`
N_PARAMS = len(PARAM_FIELDS)

# The index of each field in :attr:`SoftPVTOLParams.array`: the kernels index the parameter vector p by
# these names only (module-level ints, which numba compiles as constants). The left and the right arm's
# fields are adjacent (left first), so arm i (0 left, 1 right) reads ``p[P_ML + i]`` and ``p[P_LL + i]``.
P_M = PARAM_FIELDS.index("m")
P_ML = PARAM_FIELDS.index("m_l")
P_MR = PARAM_FIELDS.index("m_r")
P_I = PARAM_FIELDS.index("I")
P_IL = PARAM_FIELDS.index("I_l")
P_IR = PARAM_FIELDS.index("I_r")
P_LL = PARAM_FIELDS.index("l_l")
P_LR = PARAM_FIELDS.index("l_r")
P_G = PARAM_FIELDS.index("g")
P_EPS = PARAM_FIELDS.index("epsilon")
if not (P_MR == P_ML + 1 and P_IR == P_IL + 1 and P_LR == P_LL + 1):  # pragma: no cover
    raise RuntimeError("PARAM_FIELDS must keep each arm pair (left, right) adjacent: the kernels index p[P_ML + i]")

_POSITIVE = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")
_NON_NEGATIVE = ("g", "epsilon")

#: the band every mass [kg], inertia [kg m^2] and length [m] must lie in, and the largest g [m/s^2] and
#: epsilon [m]: SI values between 1e-6 and 1e6 keep every term of the model (m l^2 qdot^2, g M z, the
#: Schur complements and determinant of the mass matrix) within about 1e+-40 over the states the env
#: allows (|qdot| <= 100), far inside float64's 1e+-308, so no accepted value overflows or divides by
#: an underflowed zero. It spans a milligram to a thousand tonnes, a micrometre to a thousand km.
PARAM_MIN, PARAM_MAX = 1e-6, 1e6
#: the smallest non-zero g [m/s^2] the env takes (:class:`~softpvtol_gym.envs.config.EnvConfig`; the
#: dynamics take any g in [0, PARAM_MAX], they divide by no g): below it g is free flight for any
#: episode (1e-6 m/s^2 moves a body 0.8 mm in 40 s) while the hover thrust g M / 2 and the arm loads
#: g m_i l_i / 2 the env normalises by go toward 0 (and underflow for a subnormal g)
G_MIN = PARAM_MIN
#: unit of each field (for the messages)
PARAM_UNITS = {"m": "kg", "m_l": "kg", "m_r": "kg", "I": "kg m^2", "I_l": "kg m^2", "I_r": "kg m^2",
               "l_l": "m", "l_r": "m", "g": "m/s^2", "epsilon": "m"}
#: (lowest, highest) accepted value of each field
PARAM_BOUNDS: dict[str, tuple[float, float]] = {
    **{name: (PARAM_MIN, PARAM_MAX) for name in _POSITIVE}, "g": (0.0, PARAM_MAX), "epsilon": (0.0, PARAM_MAX)}
_KIND = {"m": "a mass", "m_l": "a mass", "m_r": "a mass", "I": "an inertia", "I_l": "an inertia",
         "I_r": "an inertia", "l_l": "a length", "l_r": "a length"}


def check_param(name: str, value) -> float:
    """``value`` of field ``name`` as a float, or a ValueError naming the field, the value, the accepted
    range and why (see :data:`PARAM_BOUNDS`)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f"SoftPVTOLParams.{name} must be a real number, got {value!r} of type {type(value).__name__}")
    v = float(value)
    unit = PARAM_UNITS[name]
    band = (f"SI values in [{PARAM_MIN:g}, {PARAM_MAX:g}] keep every term of the model, e.g. m l^2 qdot^2 and "
            "the mass matrix's inverse, far inside float64's range")
    if name in _POSITIVE:
        if not (math.isfinite(v) and PARAM_MIN <= v <= PARAM_MAX):
            raise ValueError(f"SoftPVTOLParams.{name} must be finite and > 0, in [{PARAM_MIN:g}, {PARAM_MAX:g}] "
                             f"{unit} ({_KIND[name]}; {band}), got {v!r}")
    elif not (math.isfinite(v) and 0.0 <= v <= PARAM_MAX):
        raise ValueError(f"SoftPVTOLParams.{name} must be finite and in [0, {PARAM_MAX:g}] {unit} ({band}), "
                         f"got {v!r}")
    return v


@dataclasses.dataclass(frozen=True)
class SoftPVTOLParams:
    """Parameters of the Soft-PVTOL, SI units, defaults from the paper's simulation section.

    ========== ========= ======= ==================================================================
    field      unit      default meaning
    ========== ========= ======= ==================================================================
    ``m``      kg        5.0     mass of the rigid body (paper: m)
    ``m_l``    kg        1.0     mass of the left rotor, lumped at the tip of the left arm
    ``m_r``    kg        1.0     mass of the right rotor, lumped at the tip of the right arm
    ``I``      kg m^2    1.0     moment of inertia of the body about its centre of mass
    ``I_l``    kg m^2    0.1     inertia of the left arm's bending mode (multiplies q_l_dot^2 / 2)
    ``I_r``    kg m^2    0.1     inertia of the right arm's bending mode
    ``l_l``    m         0.5     length of the left soft arm (constant curvature arc)
    ``l_r``    m         0.5     length of the right soft arm
    ``g``      m/s^2     9.8     gravitational acceleration (0: free flight)
    ``epsilon`` m        0.0     half width of the rigid frame; arms start at x = -eps and x = +eps
    ========== ========= ======= ==================================================================

    Masses, inertias and lengths must lie in [1e-6, 1e6] (SI units), ``g`` and ``epsilon`` in
    [0, 1e6] (:data:`PARAM_BOUNDS`: the band in which every term of the model stays far inside
    float64's range; the env also needs g = 0 with explicit actuator limits, or g >= 1e-6,
    :data:`G_MIN`). Invalid values raise :class:`ValueError` naming the field, the value, the range
    and the reason.
    """

    m: float = 5.0
    m_l: float = 1.0
    m_r: float = 1.0
    I: float = 1.0  # noqa: E741 (the paper's symbol)
    I_l: float = 0.1
    I_r: float = 0.1
    l_l: float = 0.5
    l_r: float = 0.5
    g: float = 9.8
    epsilon: float = 0.0

    def __post_init__(self) -> None:
        for name in PARAM_FIELDS:
            object.__setattr__(self, name, check_param(name, getattr(self, name)))

    @cached_property
    def array(self) -> np.ndarray:
        """The parameters as a read-only float64 vector in :data:`PARAM_FIELDS` order."""
        arr = np.array([getattr(self, f) for f in PARAM_FIELDS], dtype=np.float64)
        arr.setflags(write=False)
        return arr

    @property
    def total_mass(self) -> float:
        """m + m_l + m_r [kg]: the paper's Theta_1."""
        return self.m + self.m_l + self.m_r

    @property
    def hover_thrust(self) -> float:
        """Thrust per rotor [N] that holds the robot at rest with straight arms: g (m+m_l+m_r)/2."""
        return 0.5 * self.g * self.total_mass

    @property
    def arm_gravity_torques(self) -> tuple[float, float]:
        """Gravity load of each arm at zero curvature [N m]: g m_i l_i / 2 (2.45 with defaults)."""
        return 0.5 * self.g * self.m_l * self.l_l, 0.5 * self.g * self.m_r * self.l_r

    def replace(self, **changes: float) -> SoftPVTOLParams:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_array(cls, array: np.ndarray) -> SoftPVTOLParams:
        """Inverse of :attr:`array`."""
        array = np.asarray(array, dtype=np.float64)
        if array.shape != (len(PARAM_FIELDS),):
            raise ValueError(f"expected a parameter vector of shape ({len(PARAM_FIELDS)},), got {array.shape}")
        return cls(**{f: float(v) for f, v in zip(PARAM_FIELDS, array)})

