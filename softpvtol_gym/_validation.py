"""Argument checks with messages that say what was received and what is expected (and the likely fix)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: numpy dtype kinds of real numbers (int, unsigned int, float): bool, complex, str, object are refused
REAL_KINDS = "iuf"


def short_repr(value: Any, limit: int = 120) -> str:
    """repr(value), cut to ``limit`` characters (a huge array must not flood the message)."""
    r = repr(value)
    return r if len(r) <= limit else r[:limit - 5] + " ...)"


def choice(name: str, value: Any, valid) -> Any:
    """``value`` if it is one of ``valid`` (compared by identity for None, by equality for strings)."""
    valid = tuple(valid)
    if not any(value is v or (isinstance(value, str) and value == v) for v in valid):
        raise ValueError(f"{name} must be one of {list(valid)}, got {short_repr(value)}")
    return value


def positive_number(name: str, value: Any, allow_zero: bool = False) -> float:
    """``value`` as a finite float > 0 (>= 0 with ``allow_zero``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {short_repr(value)} of type {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")
    return v


def bounded_number(name: str, value: Any, low: float, high: float, why: str, *, low_open: bool = False,
                   high_open: bool = False) -> float:
    """``value`` as a float in the interval from ``low`` to ``high`` (each end closed unless ``*_open``),
    refusing what is not a real number, NaN, inf and what lies outside, with a message that names the
    argument, the value, the interval and ``why`` (the physical or numerical reason for the bounds; NaN and
    inf lie in no interval)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number in {interval_text(low, high, low_open, high_open)} ({why}), "
                         f"got {short_repr(value)} of type {type(value).__name__}")
    v = float(value)
    inside = (low < v if low_open else low <= v) and (v < high if high_open else v <= high)
    if not (math.isfinite(v) and inside):
        must = "must be finite and > 0, in" if low == 0 and low_open else "must be in"
        raise ValueError(f"{name} {must} {interval_text(low, high, low_open, high_open)} ({why}), got {value!r}")
    return v


def interval_text(low: float, high: float, low_open: bool = False, high_open: bool = False) -> str:
    """e.g. "(0, 100]"."""
    return f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


def real_array(name: str, value: Any, expected: str) -> np.ndarray:
    """``value`` as a new C-contiguous float64 array, refusing what is not an array of real numbers (strings, complex
    and bool values, None, ragged lists); shape and finiteness are the caller's. ``expected`` says what
    the caller wants (e.g. "an array of shape (4,) in [-1, 1]")."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise ValueError(f"{name} must be {expected} (real numbers), got {short_repr(value)}") from None
    if a.dtype.kind not in REAL_KINDS:
        if a.dtype.kind == "O":  # a list of numbers of mixed Python/numpy types: allowed if every one is real
            items = a.ravel().tolist()
            if items and all(isinstance(x, (int, float, np.integer, np.floating))
                             and not isinstance(x, (bool, np.bool_)) for x in items):
                try:
                    return np.array(a, dtype=np.float64, order="C")
                except (OverflowError, TypeError, ValueError):
                    pass
        what = {"b": "bool", "c": "complex", "U": "str", "S": "bytes", "O": "object", "V": "void",
                "M": "datetime", "m": "timedelta"}.get(a.dtype.kind, str(a.dtype))
        raise ValueError(f"{name} must be {expected} (real numbers), got {what} values "
                         f"(dtype {a.dtype}): {short_repr(value)}")
    return np.array(a, dtype=np.float64, order="C")


def seed_value(value: Any, name: str = "seed") -> int | None:
    """A reset seed: None or an integer >= 0 (Python or numpy integer; gymnasium's rule, numpy integers
    included), as a Python int. Bools are refused (a flag passed as a seed is a mistake)."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int >= 0 or None (e.g. {name}=0), got {short_repr(value)} of type "
                         f"{type(value).__name__}")
    if value < 0:
        raise ValueError(f"{name} must be an int >= 0 or None, got {value!r}")
    return int(value)
