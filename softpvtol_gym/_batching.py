"""Shape checking and broadcasting shared by the public batched functions."""

from __future__ import annotations

import numpy as np

from .params import SoftPVTOLParams


def as_batch(name: str, value, size: int) -> np.ndarray:
    """``value`` as a float64 array of shape (..., size), with a clear error otherwise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a real array of shape (..., {size}), got {value!r}") from exc
    if arr.ndim == 0 or arr.shape[-1] != size:
        raise ValueError(f"{name} must have shape (..., {size}), got shape {arr.shape}")
    return arr


def broadcast_batch(**arrays: tuple[object, int]) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """Broadcast the leading axes of several (..., k) inputs; returns (lead_shape, flat (N, k) arrays)."""
    checked = {name: as_batch(name, v, k) for name, (v, k) in arrays.items()}
    leads = [a.shape[:-1] for a in checked.values()]
    if all(lead == leads[0] for lead in leads):  # nothing to broadcast (the common case: fast path)
        return leads[0], [np.ascontiguousarray(a.reshape(-1, a.shape[-1])) for a in checked.values()]
    try:
        lead = np.broadcast_shapes(*(a.shape[:-1] for a in checked.values()))
    except ValueError as exc:
        shapes = ", ".join(f"{n}{a.shape}" for n, a in checked.items())
        raise ValueError(f"leading (batch) axes do not broadcast: {shapes}") from exc
    flat = [
        np.ascontiguousarray(np.broadcast_to(a, lead + a.shape[-1:]).reshape(-1, a.shape[-1]))
        for a in checked.values()
    ]
    return lead, flat


#: Largest |q_l|, |q_r| [rad] the public functions accept: the curvature power series are accurate to
#: ~1e-13 up to 2 pi (the model itself is valid for |q| <= pi, the paper's Assumption 2).
MAX_CURVATURE = 2.0 * np.pi


def check_curvature(q: np.ndarray) -> None:
    """Reject curvatures where the series evaluation is no longer accurate (never silently wrong)."""
    arms = q[..., 3:5]
    if arms.size and not np.all(np.abs(arms) <= MAX_CURVATURE):
        bad = arms[~(np.abs(arms) <= MAX_CURVATURE)]
        raise ValueError(
            f"arm curvatures must satisfy |q_l|, |q_r| <= 2 pi (the model is valid for |q| <= pi and its "
            f"power series are accurate to ~1e-13 up to 2 pi), got {bad.ravel()[:4]}; a state this bent "
            "(or NaN) usually means the simulation diverged"
        )


def param_matrix(params: SoftPVTOLParams) -> np.ndarray:
    """(1, 10) parameter matrix for the batched kernels."""
    if not isinstance(params, SoftPVTOLParams):
        raise TypeError(f"params must be a SoftPVTOLParams, got {type(params).__name__}")
    return params.array.reshape(1, -1)
