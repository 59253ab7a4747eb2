"""stable-baselines3 ``VecEnv`` adapter over :class:`SoftPVTOLVectorEnv` (no sub-processes, no copies of envs)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

try:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
except ImportError as e:
    raise ImportError("softpvtol_gym.envs.sb3 needs stable-baselines3 (and torch), which the 'train' extra "
                      'installs: pip install "softpvtol-gym[train]"') from e

from .._validation import real_array, short_repr
from .vector import SoftPVTOLVectorEnv


class SoftPVTOLSB3VecEnv(VecEnv):
    """SB3 VecEnv over the native vector env, with SB3's semantics: same-step autoreset, the last
    observation of a finished episode in ``infos[i]["terminal_observation"]``,
    ``infos[i]["TimeLimit.truncated"]`` (truncated and not terminated), and ``dones = terminated |
    truncated``. Each info dict carries the env's per-step info of that sub-env (scalars).

    ``SoftPVTOLSB3VecEnv(num_envs=8, task="hover", ...)`` or ``SoftPVTOLSB3VecEnv(vector_env=...)``.
    ``step_infos=False``: the info dicts of sub-envs whose episode goes on are empty (only a finished
    episode's dict carries the per-step info, with SB3's keys). Building a dict of 16 scalars per sub-env and
    step costs about 1.2 us per sub-env, which PPO's own training does not read (``train.py`` passes False).
    ``seed(s)`` takes effect at the next reset, seeding sub-env i with s + i.
    """

    def __init__(self, num_envs: int = 1, vector_env: SoftPVTOLVectorEnv | None = None, step_infos: bool = True,
                 **env_kwargs: Any):
        if not isinstance(step_infos, bool):
            raise ValueError(f"step_infos must be True or False, got {short_repr(step_infos)}")
        if vector_env is None:
            vector_env = SoftPVTOLVectorEnv(num_envs=num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs)
        elif env_kwargs:
            raise ValueError("pass either vector_env or env kwargs, not both")
        elif not isinstance(vector_env, SoftPVTOLVectorEnv):
            raise ValueError(f"vector_env must be a SoftPVTOLVectorEnv (autoreset_mode='SameStep') or None, got "
                             f"{short_repr(vector_env)} of type {type(vector_env).__name__}")
        if vector_env.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError("the SB3 adapter needs a SoftPVTOLVectorEnv with autoreset_mode='SameStep'")
        self.venv = vector_env
        self.config = vector_env.config
        super().__init__(vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space)
        self.step_infos = step_infos
        self._actions: np.ndarray | None = None
        self._seed: int | None = None

    # ------------------------------------------------------------------------------ VecEnv API
    def reset(self):
        obs, _ = self.venv.reset(seed=self._seed, options=self._options[0] if self._options else None)
        self._seed = None
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        # real numbers only (str, bool, complex refused, never cast); a flat batch is reshaped to (N, A),
        # any other shape is left for the vector env to refuse with the shape it expects
        a = real_array("actions", actions, f"an array of shape {(self.num_envs, *self.action_space.shape)}")
        if a.ndim == 1 and a.size == self.num_envs * self.action_space.shape[0]:
            a = a.reshape(self.num_envs, -1)
        self._actions = a

    def step_wait(self):
        obs, rew, term, trunc, info = self.venv.step(self._actions)
        dones = term | trunc
        if self.step_infos:
            infos = self._split(info)
        else:
            infos = [{} for _ in range(self.num_envs)]
        if dones.any():
            final = info["final_obs"]
            ended = np.flatnonzero(dones)
            if not self.step_infos:
                for i, entry in zip(ended.tolist(), self._split(info, ended)):
                    infos[i] = entry
            for i in ended.tolist():
                infos[i]["terminal_observation"] = final[i]
                infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, rew.astype(np.float32), dones, infos

    def _split(self, info: dict, rows: np.ndarray | None = None) -> list[dict]:
        """The vector env's info (arrays, and dicts of arrays) as one dict per sub-env (or per index of
        ``rows``), of Python scalars (each column converted once with ``tolist``)."""

        def column(v: np.ndarray) -> list:
            return (v if rows is None else v[rows]).tolist()

        n = self.num_envs if rows is None else len(rows)
        out: list[dict] = [{} for _ in range(n)]
        for k, v in info.items():
            if k.startswith("_") or k in ("final_obs", "final_info"):
                continue
            if isinstance(v, dict):
                cols = {kk: column(vv) for kk, vv in v.items()}
                for i in range(n):
                    out[i][k] = {kk: vv[i] for kk, vv in cols.items()}
            else:
                vals = column(v)
                for i in range(n):
                    out[i][k] = vals[i]
        return out

    def seed(self, seed: int | None = None):
        self._seed = seed
        return [None if seed is None else seed + i for i in range(self.num_envs)]

    def close(self) -> None:
        self.venv.close()

    def render(self, mode: str | None = None):
        return self.venv.render()

    def get_images(self):
        return [self.venv.render()]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        fn = getattr(self.venv, method_name)
        return [fn(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]
