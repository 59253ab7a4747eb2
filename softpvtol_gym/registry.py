"""The registries of tasks and robustness tiers: one generic :class:`Registry`, two instances.

A task (:class:`TaskSpec`: what the robot tracks, for how long) and a tier (:class:`TierSpec`: which
disturbance effects an episode has) are each registered once by name and looked up *live*: every
lookup (:func:`get_task`, :func:`registered_tasks`, ``softpvtol_gym.tasks.TASKS``, the env's argument
check, the baselines' command-line choices) reads the registry at the time of the call, so a task or
tier registered at run time is accepted everywhere. The built-in ones are registered by
:mod:`softpvtol_gym.tasks` and :mod:`softpvtol_gym.envs.tiers` (imported with the package).

This module imports nothing from :mod:`softpvtol_gym.envs`: ``envs`` imports it, never the reverse.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

import numpy as np

from .references import REF_CUSTOM

__all__ = [
    "Registry", "TaskSpec", "TierSpec", "EFFECT_OPTIONS", "TASK_REGISTRY", "TIER_REGISTRY",
    "register_task", "get_task", "registered_tasks", "register_tier", "get_tier", "registered_tiers",
    "MAX_EPISODE_SECONDS",
]

Spec = TypeVar("Spec")


class Registry(Generic[Spec]):
    """Specs of one kind by name, in registration order.

    Args:
        kind: what a spec is ("task", "tier"): the word of the error messages.
        spec_type: the class every registered spec is an instance of (it has a ``name``).
        register_hint: how a user registers one (named by the error of an unknown name).
        check: optional ``check(spec)`` run at registration (raises on a bad spec).
    """

    def __init__(self, kind: str, spec_type: type, register_hint: str, check: Callable | None = None):
        self.kind = kind
        self.spec_type = spec_type
        self.register_hint = register_hint
        self._check = check
        self._specs: dict[str, Spec] = {}

    def register(self, spec: Spec, *, overwrite: bool = False) -> Spec:
        """Make ``spec`` available by ``spec.name``; refuses a taken name unless ``overwrite``."""
        if not isinstance(spec, self.spec_type):
            raise TypeError(f"register_{self.kind} takes a {self.spec_type.__name__}, got {type(spec).__name__}")
        if spec.name in self._specs and not overwrite:
            raise ValueError(f"{self.kind} {spec.name!r} is already registered (pass overwrite=True to replace it)")
        if self._check is not None:
            self._check(spec)
        self._specs[spec.name] = spec
        return spec

    def get(self, name) -> Spec:
        """The spec registered as ``name``; a ValueError that lists the registered names otherwise."""
        try:
            return self._specs[name]
        except (KeyError, TypeError):
            raise ValueError(f"{self.kind} must be one of the registered {self.kind}s {list(self._specs)}, got "
                             f"{name!r} ({self.register_hint})") from None

    def names(self) -> tuple[str, ...]:
        """The registered names now, in registration order."""
        return tuple(self._specs)

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in self._specs

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._specs)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {list(self._specs)})"


# ------------------------------------------------------------------------------------------- tasks
#: the longest episode [s] a task or ``max_episode_seconds`` may ask for (about 32 years)
MAX_EPISODE_SECONDS = 1e9
EPISODE_SECONDS_REASON = ("the episode clock t = steps x dt then keeps a resolution below 1e-6 s in float64 and the "
                          "step count fits an int64 at any frame_skip")
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
        compiled_reference, sampler: internal (the built-in tasks' compiled reference and episode sampler:
            :mod:`softpvtol_gym.references`, ``SAMPLE_*``).
    """

    name: str
    reference: Callable
    episode_seconds: float
    initial_state: Callable | None = None
    view: tuple | None = None
    compiled_reference: int = REF_CUSTOM
    sampler: int = SAMPLE_CUSTOM

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"TaskSpec.name must be a non-empty str, got {self.name!r}")
        if not callable(self.reference):
            raise ValueError(f"TaskSpec.reference must be callable as reference(t) -> (pos, vel, acc), "
                             f"got {self.reference!r}")
        e = self.episode_seconds
        if isinstance(e, (bool, np.bool_)) or not isinstance(e, (int, float, np.integer, np.floating)) or not (
                math.isfinite(e) and 0 < e <= MAX_EPISODE_SECONDS):
            raise ValueError(f"TaskSpec.episode_seconds must be a finite number in (0, {MAX_EPISODE_SECONDS:g}] [s] "
                             f"({EPISODE_SECONDS_REASON}), got {e!r}")
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
        return self.compiled_reference != REF_CUSTOM

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


def _check_task(spec: TaskSpec) -> None:
    spec.evaluate(np.array([0.0, 1.0]))  # the reference is checked once, at t = 0 and 1 s


#: the task registry (built-in tasks: :mod:`softpvtol_gym.tasks`)
TASK_REGISTRY: Registry[TaskSpec] = Registry("task", TaskSpec, "register your own with "
                                             "softpvtol_gym.tasks.register_task", _check_task)


def register_task(spec: TaskSpec, *, overwrite: bool = False) -> TaskSpec:
    """Make ``spec`` available to every env by name (its reference is checked once at t = 0 and 1 s)."""
    return TASK_REGISTRY.register(spec, overwrite=overwrite)


def get_task(name) -> TaskSpec:
    """The registered task ``name``; a ValueError that lists the registered ones otherwise."""
    return TASK_REGISTRY.get(name)


def registered_tasks() -> tuple[str, ...]:
    """The names of the tasks registered now (built-in ones first)."""
    return TASK_REGISTRY.names()


# ------------------------------------------------------------------------------------------- tiers
#: the effects a tier can switch on and the options that parametrise each (an option given by hand
#: switches its effect on); each effect is a branch of the env's step kernel (:mod:`softpvtol_gym.envs.tiers`)
EFFECT_OPTIONS = {
    "mismatch": ("mismatch_scale",),
    "wind": ("wind_std", "wind_correlation_time"),
    "noise": ("obs_noise_scale",),
    "lag": ("actuator_time_constant",),
    # the plant integrates the consistent model (docs/model.md) while the controllers keep the paper's
    "consistent_plant": (),
}


@dataclasses.dataclass(frozen=True)
class TierSpec:
    """A robustness tier: ``name`` and the ``effects`` it switches on (keys of :data:`EFFECT_OPTIONS`;
    "consistent_plant" has no options: the plant integrates ``model="consistent"``)."""

    name: str
    effects: tuple = ()
    description: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"TierSpec.name must be a non-empty str, got {self.name!r}")
        unknown = [e for e in self.effects if e not in EFFECT_OPTIONS]
        if unknown:
            raise ValueError(f"unknown tier effects {unknown}; valid ones are {sorted(EFFECT_OPTIONS)}")
        object.__setattr__(self, "effects", tuple(self.effects))


#: the tier registry (built-in tiers: :mod:`softpvtol_gym.envs.tiers`)
TIER_REGISTRY: Registry[TierSpec] = Registry("tier", TierSpec, "register your own with "
                                             "softpvtol_gym.envs.register_tier")


def register_tier(spec: TierSpec, *, overwrite: bool = False) -> TierSpec:
    """Make a tier available to every env by name."""
    return TIER_REGISTRY.register(spec, overwrite=overwrite)


def get_tier(name) -> TierSpec:
    """The registered tier ``name``; a ValueError that lists the registered ones otherwise."""
    return TIER_REGISTRY.get(name)


def registered_tiers() -> tuple[str, ...]:
    """The names of the tiers registered now (built-in ones first)."""
    return TIER_REGISTRY.names()
