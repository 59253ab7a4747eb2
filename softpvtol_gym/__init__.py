"""softpvtol-gym: a Gymnasium environment for the Soft-PVTOL soft aerial robot."""

from __future__ import annotations

from . import dynamics, integrators
from .params import PARAM_FIELDS, SoftPVTOLParams

__version__ = "0.1.0"

__all__ = ["SoftPVTOLParams", "PARAM_FIELDS", "dynamics", "integrators", "__version__"]
