"""Tasks: what the robot tracks and for how long, declared once in a registry.

A task is a :class:`TaskSpec`. :func:`register_task` makes it available by name to
``gym.make("SoftPVTOL-v0", task=name)``, the native vector env, :class:`~softpvtol_gym.PassivityPolicy`
and the renderer, with no edit to the package::

    import numpy as np
    from softpvtol_gym.tasks import TaskSpec, register_task

    def figure_eight(t):                      # t: (N,) episode times [s]
        pos = np.stack([2 * np.sin(0.5 * t), 3 + np.sin(t), 0 * t], axis=1)
        vel = np.stack([np.cos(0.5 * t), np.cos(t), 0 * t], axis=1)
        acc = np.stack([-0.5 * np.sin(0.5 * t), -np.sin(t), 0 * t], axis=1)
        return pos, vel, acc                  # each (N, 3): (x [m], z [m], theta [rad]) and rates

    register_task(TaskSpec("figure_eight", figure_eight, episode_seconds=20.0))
    env = gym.make("SoftPVTOL-v0", task="figure_eight")

The built-in tasks (hover, setpoint, track_paper, track_random) are registered the same way; their
references are also compiled into the step kernel (``compiled_reference``) and have per-episode
parameters (set-point, sinusoids), so their ``reference(t, refp=None)`` takes those parameters
(None: the task's nominal ones).

The registry itself is :mod:`softpvtol_gym.registry` (shared with the tiers); this module re-exports
its task functions. ``TASKS`` is a live lookup: the names registered at the time it is read (as
:func:`registered_tasks`); :data:`BUILTIN_TASKS` are the four built-in ones.

A registered task lives in the registry of the process that registered it: with subprocess vector
envs, register it in a module the workers import too (see README, "Custom tasks").
"""

from __future__ import annotations

import math

import numpy as np

from . import references as _ref
from .registry import (
    SAMPLE_CUSTOM,
    SAMPLE_HOVER,
    SAMPLE_PAPER,
    SAMPLE_RANDOM,
    SAMPLE_SETPOINT,
    TaskSpec,
    get_task,
    register_task,
    registered_tasks,
)

__all__ = [
    "TASKS",  # noqa: F822 (a live lookup: module __getattr__)
    "TaskSpec", "register_task", "get_task", "registered_tasks", "BUILTIN_TASKS", "HOVER_SETPOINT", "PAPER_Q0",
    "SAMPLE_CUSTOM", "SAMPLE_HOVER", "SAMPLE_SETPOINT", "SAMPLE_PAPER", "SAMPLE_RANDOM",
]


# ---------------------------------------------------------------------------------- built-in tasks
#: the hover task's set-point (x, z, theta) and the paper's initial state
HOVER_SETPOINT = (0.0, 2.0, 0.0)
PAPER_Q0 = (5.0, 0.0, 0.2 * math.pi, 0.01 * math.pi, -0.15 * math.pi)


class CompiledReference:
    """``reference(t, refp=None)`` of a built-in task: its compiled reference ``code`` with the
    per-episode parameters refp (N, 21), or (None) the task's nominal ones. Picklable."""

    def __init__(self, code: int, nominal: tuple):
        self.code = code
        self.nominal = np.zeros(_ref.N_REF_PARAMS)
        self.nominal[:len(nominal)] = nominal

    def __call__(self, t, refp=None):
        return _ref.evaluate(self.code, t, self.nominal if refp is None else refp)

    def __repr__(self) -> str:
        return f"CompiledReference({self.code}, nominal={self.nominal[:3].tolist()}...)"


def _compiled(code: int, nominal: tuple) -> CompiledReference:
    return CompiledReference(code, nominal)


_BUILTIN = (
    TaskSpec("hover", _compiled(_ref.REF_CONSTANT, HOVER_SETPOINT), 10.0, view=(-4.0, 4.0, -1.5),
             compiled_reference=_ref.REF_CONSTANT, sampler=SAMPLE_HOVER),
    TaskSpec("setpoint", _compiled(_ref.REF_CONSTANT, HOVER_SETPOINT), 10.0, view=(-5.0, 5.0, -1.5),
             compiled_reference=_ref.REF_CONSTANT, sampler=SAMPLE_SETPOINT),
    TaskSpec("track_paper", _compiled(_ref.REF_PAPER, ()), 40.0, view=(-7.5, 7.5, -1.5),
             compiled_reference=_ref.REF_PAPER, sampler=SAMPLE_PAPER),
    TaskSpec("track_random", _compiled(_ref.REF_SINUSOIDS, (0.0, 3.0)), 20.0, view=(-5.0, 5.0, -1.0),
             compiled_reference=_ref.REF_SINUSOIDS, sampler=SAMPLE_RANDOM),
)
for _spec in _BUILTIN:
    register_task(_spec)
#: the names of the built-in tasks (``TASKS``: every registered one)
BUILTIN_TASKS: tuple[str, ...] = tuple(s.name for s in _BUILTIN)


def __getattr__(name: str):
    """``TASKS``: the names of the tasks registered now (a live lookup, PEP 562)."""
    if name == "TASKS":
        return registered_tasks()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | {"TASKS"})
