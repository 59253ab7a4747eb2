"""What the policies share: observations checked and shaped for ``predict``, the env's config of an env,
the actuators scaled to the env's action, and the buffers of the one-observation path."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._batching import MAX_CURVATURE
from .._validation import real_array, short_repr
from ..envs.config import EnvConfig
from ..envs.observation import OBS_DIM, OBS_NAMES

_F64 = np.dtype(np.float64)


@njit(cache=True, nogil=True)
def _observations_ok(obs, qmax):
    """True if every entry of obs (N, 18) is finite and |q_l|, |q_r| (columns 5, 6) <= qmax (one
    compiled pass: cheaper than the ufunc calls for the single observations of an evaluation loop)."""
    for n in range(obs.shape[0]):
        for k in range(obs.shape[1]):
            if not math.isfinite(obs[n, k]):
                return False
        if not (abs(obs[n, 5]) <= qmax and abs(obs[n, 6]) <= qmax):
            return False
    return True


def _check_observation(obs: np.ndarray) -> None:
    """Observations (N, 18) the controller can act on: finite, arm curvatures inside the model's
    validity (the controller's series are accurate up to 2 pi; the env ends an episode beyond pi)."""
    if _observations_ok(obs, MAX_CURVATURE):
        return
    if not np.isfinite(obs).all():
        rows, cols = np.nonzero(~np.isfinite(obs))
        raise ValueError(f"observation must be finite, got {obs[rows[0], cols[0]]} at "
                         f"{'index ' + str(cols[0]) if obs.shape[0] == 1 else f'[{rows[0]}, {cols[0]}]'} "
                         f"({OBS_NAMES[cols[0]]})")
    arms = obs[:, 5:7]
    bad = ~(np.abs(arms) <= MAX_CURVATURE)
    if bad.any():
        rows, cols = np.nonzero(bad)
        r, c = rows[0], cols[0] + 5
        raise ValueError(
            f"observation {'index ' + str(c) if obs.shape[0] == 1 else f'[{r}, {c}]'} ({OBS_NAMES[c]}) = "
            f"{float(obs[r, c])!r} is outside the model's validity: the controller needs arm curvatures "
            f"|q_l|, |q_r| <= 2 pi (the model holds for |q| <= pi; the env ends an episode beyond pi as "
            f"'curvature_limit', and clips observations at +-1e6 only after a divergence); act on observations "
            f"of running episodes"
        )


def policy_observations(observation, dim: int) -> tuple[np.ndarray, bool]:
    """(obs (N, 18) float64, single) of the analytic policies' ``predict``: ``observation`` (dim,) or (N,
    dim) of the policy's env (dim 18, or 21 with its ``observe_error_integral``: the controllers read
    entries 0-17), checked (real numbers, the shape, finite, arm curvatures inside the model's validity);
    a ValueError naming what was received otherwise."""
    obs = observation
    if type(obs) is np.ndarray and obs.dtype.kind == "f":  # the common case (float32 from the env)
        if not (obs.dtype is _F64 and obs.flags.c_contiguous and obs.flags.writeable):
            obs = obs.astype(_F64)  # (a C-contiguous copy)
    else:
        obs = real_array("observation", observation, f"an array of shape ({dim},) or (N, {dim})")
    single = obs.ndim == 1
    if obs.ndim not in (1, 2) or obs.shape[-1] != dim or obs.shape[0] == 0:
        raise ValueError(f"observation must have shape ({dim},) or (N, {dim}) with N >= 1 (the observation of "
                         f"the policy's env), got shape {obs.shape}")
    obs = obs.reshape(-1, dim)
    if dim != OBS_DIM:  # the controllers read entries 0-17; the error integrals are the env's, not their memory
        obs = np.ascontiguousarray(obs[:, :OBS_DIM])
    _check_observation(obs)
    return obs, single


def state_from_observation(obs: np.ndarray) -> tuple[np.ndarray, ...]:
    """(q, qdot, q_ref, qdot_ref, qddot_ref), each (N, 5), from observations (N, 18)."""
    obs = np.asarray(obs, dtype=np.float64)
    n = obs.shape[0]
    theta = np.arctan2(obs[:, 3], obs[:, 4])
    q = np.zeros((n, 5))
    q[:, 0], q[:, 1], q[:, 2], q[:, 3], q[:, 4] = obs[:, 0], obs[:, 1], theta, obs[:, 5], obs[:, 6]
    q_ref = np.zeros((n, 5))
    q_ref[:, 2] = theta - obs[:, 2]
    qd = obs[:, 7:12].copy()
    qdr = np.zeros((n, 5))
    qdr[:, :3] = obs[:, 12:15]
    qddr = np.zeros((n, 5))
    qddr[:, :3] = obs[:, 15:18]
    return q, qd, q_ref, qdr, qddr


def _episode_start_mask(episode_start, n: int) -> np.ndarray:
    """``episode_start`` as a bool mask of n entries: a bool (or 0/1) scalar, or N of them."""
    a = np.asarray(episode_start)
    if a.dtype.kind not in "biuf" or a.size not in (1, n) or (a.dtype.kind != "b" and not np.isin(a, (0, 1)).all()):
        raise ValueError(f"episode_start must be None, a bool or a bool array of {n} entries (one per "
                         f"observation), got {short_repr(episode_start)}"
                         + (f" with {a.size} entries" if a.dtype.kind in "biuf" and a.size not in (1, n) else ""))
    mask = a.astype(bool).reshape(-1)
    return np.repeat(mask, n) if mask.size == 1 and n > 1 else mask


def env_config(env) -> EnvConfig:
    """The :class:`EnvConfig` of a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter
    (what the policies' ``from_env`` build from); ValueError for anything else."""
    cfg = getattr(env, "config", None)
    if cfg is None and hasattr(env, "unwrapped"):
        cfg = getattr(env.unwrapped, "config", None)
    if cfg is None and hasattr(env, "venv"):
        cfg = getattr(env.venv, "config", None)
    if cfg is None and hasattr(env, "get_wrapper_attr"):
        cfg = env.get_wrapper_attr("config")
    if not isinstance(cfg, EnvConfig):
        raise ValueError(f"env must be a SoftPVTOLEnv / SoftPVTOLVectorEnv (wrapped or not) or the SB3 adapter: "
                         f"cannot find a SoftPVTOL EnvConfig on {short_repr(env)}")
    return cfg


class _OneObservationPath:
    """What PassivityPolicy and ExtendedPolicy share for their one-observation path: the buffers
    (:class:`_OneObservation`), built at first use and left out of a copy (they hold views of themselves, which a
    copy would turn into independent arrays)."""

    _one = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_one": None}

    def _load_one(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_OneObservation.load` of the policy's buffers."""
        if self._one is None:
            self._one = _OneObservation()
        return self._one.load(observation)


#: the shape of one observation that PassivityPolicy.predict takes its short path for
_ONE_OBS = (OBS_DIM,)


def _is_one_observation(observation) -> bool:
    """Whether the policies' one-observation path takes ``observation``: a float array of shape (18,)."""
    return type(observation) is np.ndarray and observation.shape == _ONE_OBS and observation.dtype.kind == "f"


class _OneObservation:
    """The policies' buffers for one observation (the path of an evaluation loop): the observation (1, 18)
    float64, its sin and cos columns (views) and theta (1,). Not copied with a policy (it holds views of
    itself): the policies leave it out of their pickled state and build it again at first use."""

    __slots__ = ("obs", "sin", "cos", "theta")

    def __init__(self):
        self.obs = np.empty((1, OBS_DIM))
        self.sin, self.cos, self.theta = self.obs[:, 3], self.obs[:, 4], np.empty(1)

    def load(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(obs (1, 18), theta (1,)) of a float observation (18,): copied, checked as policy_observations
        checks it, theta by numpy's arctan2 as state_from_observation (the same values as the general path)."""
        obs = self.obs
        obs[0] = observation
        if not _observations_ok(obs, MAX_CURVATURE):
            _check_observation(obs)
        np.arctan2(self.sin, self.cos, out=self.theta)
        return obs, self.theta
