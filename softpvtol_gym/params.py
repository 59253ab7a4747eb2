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
    ``g``      m/s^2     9.8     gravitational acceleration (0 allowed: free flight)
    ``epsilon`` m        0.0     half width of the rigid frame; arms start at x = -eps and x = +eps
    ========== ========= ======= ==================================================================

    Masses, inertias and lengths must be finite and > 0; ``g`` and ``epsilon`` finite and >= 0.
    Invalid values raise :class:`ValueError` naming the field.
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
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise ValueError(
                    f"SoftPVTOLParams.{name} must be a real number, got {value!r} "
                    f"of type {type(value).__name__}"
                )
            value = float(value)
            if name in _POSITIVE and not (math.isfinite(value) and value > 0.0):
                raise ValueError(
                    f"SoftPVTOLParams.{name} must be finite and > 0 (a mass, inertia or length), "
                    f"got {value!r}"
                )
            if name in _NON_NEGATIVE and not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"SoftPVTOLParams.{name} must be finite and >= 0, got {value!r}")
            object.__setattr__(self, name, value)

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

