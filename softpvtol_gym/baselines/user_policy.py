"""Policies brought by a user: a ``MODULE:FACTORY`` spec loaded (:func:`load_factory`), and what the factory
returns turned into a policy with a checked ``predict`` (:func:`as_policy`).

``MODULE`` is a dotted module name importable from the current directory (``my_pkg.controllers``) or a path to a
``.py`` file (anything that ends with ``.py`` or holds a path separator is a path);
``FACTORY`` is the name of a callable in it. ``FACTORY(env)`` gets a one-env
:class:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv` of the task, tier and action mode to be scored (its
``single_observation_space`` and ``single_action_space`` say the shapes) and returns one of:

* an object with a stable-baselines3 ``predict(observation, state=None, episode_start=None, deterministic=True)
  -> (action, state)`` (an SB3 model, :class:`softpvtol_gym.PassivityPolicy`, ...);
* a plain callable ``observation -> action``.

Observations come as a batch (n, obs_dim) during the episodes and one at a time (obs_dim,) in the per-robot
compute pass; actions must be (n, action_dim), or (action_dim,) for one observation. Every problem is a
:class:`~softpvtol_gym.baselines.errors.ConfigError` of one line saying what was received and what is expected.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np

from softpvtol_gym._validation import short_repr
from softpvtol_gym.baselines.errors import ConfigError

SPEC_FORM = ("MODULE:FACTORY (MODULE: a dotted module importable from the current directory, or a path to a .py "
             "file; FACTORY: the name of a callable in it, called with the env)")


def load_factory(spec: str):
    """The callable named by ``spec`` (``MODULE:FACTORY``, see the module docstring)."""
    if not isinstance(spec, str) or ":" not in spec:
        raise ConfigError(f"--policy must be {SPEC_FORM}, got {spec!r}")
    module_name, _, name = spec.rpartition(":")
    if not module_name or not name.isidentifier():
        raise ConfigError(f"--policy must be {SPEC_FORM}, got {spec!r}")
    module = _import_file(module_name) if _is_path(module_name) else _import_module(module_name)
    factory = getattr(module, name, None)
    if factory is None:
        raise ConfigError(f"--policy {spec}: {module_name} has no attribute {name!r}; expected a callable that takes "
                          f"the env")
    if not callable(factory):
        raise ConfigError(f"--policy {spec}: {name} is a {type(factory).__name__}, not callable; expected a callable "
                          f"that takes the env")
    return factory


def _is_path(module_name: str) -> bool:
    return module_name.endswith(".py") or "/" in module_name or os.sep in module_name


def _import_file(path_name: str):
    path = Path(path_name)
    if not path.is_file():
        raise ConfigError(f"--policy: no Python file at {path} (a MODULE that is a path must name a .py file)")
    spec = importlib.util.spec_from_file_location(f"softpvtol_user_policy_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ConfigError(f"--policy: {path} cannot be imported as a Python module; expected a .py file")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - the user's code: its error in one line
        raise ConfigError(f"--policy: importing {path} failed: it {failure_words(exc)}") from None
    return module


def _import_module(module_name: str):
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:  # importable from the current directory, as `python -m` does
        sys.path.insert(0, cwd)
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            raise ConfigError(f"--policy: module {module_name!r} not found (it must be importable from the current "
                              f"directory {cwd}, or pass a path to a .py file)") from None
        raise ConfigError(f"--policy: importing {module_name} failed: {exc}") from None
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - the user's code: its error in one line
        raise ConfigError(f"--policy: importing {module_name} failed: it {failure_words(exc)}") from None


def as_policy(obj, env, where: str = "the policy factory") -> CheckedPolicy:
    """``obj`` (what a factory returned for ``env``) as a policy whose actions are checked against ``env``'s action
    space: its own ``predict`` if it has one, else ``obj`` called on the observation."""
    if callable(getattr(obj, "predict", None)):
        call = obj.predict
        returns_state = True
    elif callable(obj):
        call = obj
        returns_state = False
    else:
        raise ConfigError(f"{where} returned a {type(obj).__name__}, which has no predict method and is not "
                          f"callable; expected an object with predict(observation, state=None, episode_start=None, "
                          f"deterministic=True) -> (action, state), an SB3 model, or a callable observation -> action")
    return CheckedPolicy(call, returns_state, int(np.prod(env.single_action_space.shape)), where)


class CheckedPolicy:
    """A stable-baselines3 ``predict`` over a user's policy; every call checks what it returns (real numbers, the
    shape, finite) and turns an error of the policy's own, ``sys.exit`` included, into a ConfigError of one line
    naming it."""

    def __init__(self, call, returns_state: bool, action_dim: int, where: str):
        self._call, self._returns_state, self.action_dim, self._where = call, returns_state, action_dim, where

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        try:
            if self._returns_state:
                out = self._call(observation, state=state, episode_start=episode_start, deterministic=deterministic)
                action = out[0] if isinstance(out, tuple) else out
            else:
                action = self._call(observation)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - the user's code: its error in one line
            raise ConfigError(f"{self._where}: the policy {failure_words(exc)} on observations of shape "
                              f"{np.shape(observation)}") from None
        return self._check(action, np.shape(observation)), None

    def _check(self, action, obs_shape: tuple) -> np.ndarray:
        try:
            values = np.asarray(action, dtype=float)
        except (TypeError, ValueError):
            values = None
        if values is None or np.asarray(action).dtype.kind in "bc":
            raise ConfigError(f"{self._where}: the policy returned {type(action).__name__} "
                              f"{short_repr(action, 80).replace(chr(10), ' ')} for observations of shape "
                              f"{obs_shape}; expected real numbers, an array of {self.action_dim} actions per env")
        want = (obs_shape[0], self.action_dim) if len(obs_shape) == 2 else (self.action_dim,)
        if values.shape != want and not (len(obs_shape) == 1 and values.shape == (1, self.action_dim)):
            raise ConfigError(f"{self._where}: the policy returned actions of shape {values.shape} for observations "
                              f"of shape {obs_shape}; expected {want} (one row of {self.action_dim} actions per env)")
        if not np.isfinite(values).all():
            bad = values.reshape(-1)[~np.isfinite(values.reshape(-1))][0]
            raise ConfigError(f"{self._where}: the policy returned a non-finite action ({bad}) for observations of "
                              f"shape {obs_shape}; expected finite actions")
        return values.reshape(want)


def failure_words(exc: BaseException) -> str:
    """What a user's code did, in a few words: ``raised ValueError: ...`` or ``called sys.exit(0)``."""
    if isinstance(exc, SystemExit):
        return f"called sys.exit({exc.code!r})"
    return f"raised {type(exc).__name__}: {exc}".replace("\n", " ")
