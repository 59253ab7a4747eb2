"""Argument checks with messages that say what was received and what is expected."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def choice(name: str, value: Any, valid) -> Any:
    """``value`` if it is one of ``valid`` (compared by identity for None, by equality for strings)."""
    valid = tuple(valid)
    if not any(value is v or (isinstance(value, str) and value == v) for v in valid):
        raise ValueError(f"{name} must be one of {list(valid)}, got {value!r}")
    return value


def positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a finite float > 0 (>= 0 with ``allow_zero``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r} of type {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v
