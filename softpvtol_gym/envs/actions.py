"""Action modes, declared once: each names its kernel branch and its action dimension.

The kernel branches (``MODE_*``) live in :func:`softpvtol_gym.envs.command.command`; a new mode is one
:class:`ActionModeSpec` here plus its branch there.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

#: kernel codes of the applied-command path
MODE_ACT, MODE_VIRTUAL, MODE_IDEAL, MODE_RES_ACT = 0, 1, 2, 3


@dataclasses.dataclass(frozen=True)
class ActionModeSpec:
    """``kernel_mode(cfg)`` and ``action_dim(cfg)`` of an :class:`~softpvtol_gym.envs.config.EnvConfig`."""

    name: str
    description: str
    kernel_mode: Callable
    action_dim: Callable


ACTION_MODE_SPECS = {
    s.name: s
    for s in (
        ActionModeSpec("actuators", "thrusts and arm torques (T_l, T_r, tau_l, tau_r), normalised",
                       lambda cfg: MODE_ACT, lambda cfg: 4),
        ActionModeSpec("virtual", "generalized force tau (5), through the allocation or applied ('ideal')",
                       lambda cfg: MODE_IDEAL if cfg.resolved_allocation == "ideal" else MODE_VIRTUAL,
                       lambda cfg: 5),
        ActionModeSpec("residual", "correction on top of the passivity controller (tau, or actuators)",
                       lambda cfg: MODE_RES_ACT, lambda cfg: 5 if cfg.residual_space == "virtual" else 4),
    )
}
ACTION_MODES = tuple(ACTION_MODE_SPECS)


def actuator_action(actuators: np.ndarray, thrust_max: float, arm_torque_max: float) -> np.ndarray:
    """The env's normalised action (unclipped) of actuators (..., 4) = (T_l, T_r, tau_l, tau_r):
    thrusts [0, T_max] -> [-1, 1] (2 T / T_max - 1), arm torques [-tau_max, tau_max] -> [-1, 1]
    (the compiled path of :class:`PassivityPolicy` writes the same formula in its kernel)."""
    a = np.asarray(actuators, dtype=np.float64)
    u = np.empty(a.shape)
    u[..., 0:2] = 2.0 * a[..., 0:2] / thrust_max - 1.0
    u[..., 2:4] = a[..., 2:4] / arm_torque_max
    return u


def action_actuators(action: np.ndarray, thrust_max: float, arm_torque_max: float) -> np.ndarray:
    """The actuators (..., 4) = (T_l, T_r, tau_l, tau_r) of the env's normalised action (..., 4), clipped to
    [-1, 1] as the env clips it: the inverse of :func:`actuator_action`."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    u = np.empty(a.shape)
    u[..., 0:2] = 0.5 * (a[..., 0:2] + 1.0) * thrust_max
    u[..., 2:4] = a[..., 2:4] * arm_torque_max
    return u
