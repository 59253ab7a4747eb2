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

A registered task lives in the registry of the process that registered it: with subprocess vector
envs, register it in a module the workers import too (see README, "Custom tasks").
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from .envs import references as _ref

__all__ = ["TaskSpec", "register_task", "get_task", "registered_tasks", "TASKS"]

#: episode-sampling codes of the compiled sampler (``envs.episodes``); SAMPLE_CUSTOM: reference + perturbation
SAMPLE_CUSTOM, SAMPLE_HOVER, SAMPLE_SETPOINT, SAMPLE_PAPER, SAMPLE_RANDOM = -1, 0, 1, 2, 3


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """A task.

    Args:
        name: the name ``gym.make(..., task=name)`` takes.
        reference: ``reference(t) -> (pos, vel, acc)``: t a float64 array (N,) of episode times [s];
            pos, vel, acc each (N, 3): the body reference (x [m], z [m], theta [rad]) and its first and
            second time derivatives. The arm curvatures have no reference (the controller allocates them).
        episode_seconds: episode length [s] (truncation; ``max_episode_seconds`` overrides it).
        initial_state: optional ``initial_state(u) -> (q0, qdot0)``, u (N, 10) uniforms in [0, 1) from
            the env's RNG, q0 and qdot0 (N, 5). Default: the reference at t = 0 (arms straight, at rest)
            plus the hover perturbation (x, z +/- 1 m, theta and arms +/- 0.3 rad, xdot, zdot +/- 0.5 m/s,
            angular rates +/- 0.2 rad/s, uniform).
        view: optional renderer window (x_min [m], x_max [m], z_min [m]); default: fitted to the
            reference's x range over the episode.
        compiled_reference, sampler: internal (the built-in tasks' compiled reference and episode sampler).
    """

    name: str
    reference: Callable
    episode_seconds: float
    initial_state: Callable | None = None
    view: tuple | None = None
    compiled_reference: int = _ref.REF_CUSTOM
    sampler: int = SAMPLE_CUSTOM

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"TaskSpec.name must be a non-empty str, got {self.name!r}")
        if not callable(self.reference):
            raise ValueError(f"TaskSpec.reference must be callable as reference(t) -> (pos, vel, acc), "
                             f"got {self.reference!r}")
        e = self.episode_seconds
        if isinstance(e, bool) or not isinstance(e, (int, float, np.integer, np.floating)) or not (
                math.isfinite(e) and e > 0):
            raise ValueError(f"TaskSpec.episode_seconds must be a finite number > 0 [s], got {e!r}")
        object.__setattr__(self, "episode_seconds", float(e))
        if self.initial_state is not None and not callable(self.initial_state):
            raise ValueError(f"TaskSpec.initial_state must be None or callable as initial_state(u) -> (q0, qdot0), "
                             f"got {self.initial_state!r}")
        if self.view is not None:
            v = tuple(self.view)
            if len(v) != 3 or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in v) or v[1] <= v[0]:
                raise ValueError(f"TaskSpec.view must be (x_min, x_max, z_min) with x_max > x_min, got {self.view!r}")
            object.__setattr__(self, "view", tuple(float(x) for x in v))

    @property
    def is_compiled(self) -> bool:
        return self.compiled_reference != _ref.REF_CUSTOM

    def evaluate(self, t, refp=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos, vel, acc), each (N, 3), at times t (N,), checked: a clear error for a reference that
        returns the wrong shapes or non-finite values."""
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        if self.is_compiled:
            return self.reference(t, refp)
        out = self.reference(t)
        if not (isinstance(out, tuple) and len(out) == 3):
            raise ValueError(f"task {self.name!r}: reference(t) must return a tuple (pos, vel, acc), got {type(out)}")
        res = []
        for what, a in zip(("pos", "vel", "acc"), out):
            a = np.asarray(a, dtype=np.float64)
            if a.shape != (t.shape[0], 3):
                raise ValueError(f"task {self.name!r}: reference(t) for t of shape {t.shape} must return {what} of "
                                 f"shape {(t.shape[0], 3)}, got {a.shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"task {self.name!r}: reference(t) returned a non-finite {what} at t = {t[:4]}...")
            res.append(a)
        return tuple(res)


_TASKS: dict[str, TaskSpec] = {}


def register_task(spec: TaskSpec, *, overwrite: bool = False) -> TaskSpec:
    """Make ``spec`` available to every env by name (its reference is checked once at t = 0 and 1 s)."""
    if not isinstance(spec, TaskSpec):
        raise TypeError(f"register_task takes a TaskSpec, got {type(spec).__name__}")
    if spec.name in _TASKS and not overwrite:
        raise ValueError(f"task {spec.name!r} is already registered (pass overwrite=True to replace it)")
    spec.evaluate(np.array([0.0, 1.0]))
    _TASKS[spec.name] = spec
    return spec


def get_task(name) -> TaskSpec:
    """The registered task ``name``; a ValueError that lists the registered ones otherwise."""
    try:
        return _TASKS[name]
    except (KeyError, TypeError):
        raise ValueError(f"task must be one of the registered tasks {list(_TASKS)}, got {name!r} "
                         "(register your own with softpvtol_gym.tasks.register_task)") from None


def registered_tasks() -> tuple[str, ...]:
    return tuple(_TASKS)


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


for _spec in (
    TaskSpec("hover", _compiled(_ref.REF_CONSTANT, HOVER_SETPOINT), 10.0, view=(-4.0, 4.0, -1.5),
             compiled_reference=_ref.REF_CONSTANT, sampler=SAMPLE_HOVER),
    TaskSpec("setpoint", _compiled(_ref.REF_CONSTANT, HOVER_SETPOINT), 10.0, view=(-5.0, 5.0, -1.5),
             compiled_reference=_ref.REF_CONSTANT, sampler=SAMPLE_SETPOINT),
    TaskSpec("track_paper", _compiled(_ref.REF_PAPER, ()), 40.0, view=(-7.5, 7.5, -1.5),
             compiled_reference=_ref.REF_PAPER, sampler=SAMPLE_PAPER),
    TaskSpec("track_random", _compiled(_ref.REF_SINUSOIDS, (0.0, 3.0)), 20.0, view=(-5.0, 5.0, -1.0),
             compiled_reference=_ref.REF_SINUSOIDS, sampler=SAMPLE_RANDOM),
):
    register_task(_spec)
#: the built-in tasks
TASKS = registered_tasks()
