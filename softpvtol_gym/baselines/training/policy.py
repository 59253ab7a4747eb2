"""LearnedPolicy: an SB3 model plus its observation normalisation and frame stack, with SB3's ``predict``
on raw observations of the native vector env."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.load import load_folder
from softpvtol_gym.baselines.checkpoints.sb3_compat import load_pickled
from softpvtol_gym.baselines.checkpoints.store import (
    find_checkpoint,
)
from softpvtol_gym.baselines.config.hyperparams import frame_stack
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.training.lean import LeanMLPPolicy, checked_observations, is_zero_at_zero
from softpvtol_gym.baselines.training.stacking import ObservationStack, frame_stack_wrapper

#: how a LearnedPolicy computes its actions: ``lean`` (:class:`~.lean.LeanMLPPolicy`: a compiled float64 pass
#: per observation row, the same action whatever the batch) or ``torch`` (the model's own float32 forward)
INFERENCE = ("lean", "torch")


class LearnedPolicy:
    """An SB3 model plus its observation normalisation and frame stack, with SB3's ``predict`` on raw
    observations of the native vector env.

    ``inference``: ``"lean"`` (the default) computes the deterministic action with
    :class:`~softpvtol_gym.baselines.training.lean.LeanMLPPolicy`, a compiled float64 forward pass of the actor
    per observation row: an episode's actions do not depend on how many episodes are evaluated beside it, and
    they equal torch's to float32 rounding (about 1e-7). ``"torch"`` runs SB3's own ``predict`` (float32, a
    batch-dependent summation order; needed to sample with ``deterministic=False`` and for what the lean path
    does not compute: gSDE, other activations or feature extractors). The lean path copies the weights when the
    policy is built: build it again after training further.

    ``frame_stack`` (K, the run's ``frame_stack`` hyperparameter; None: the K of the VecFrameStack the model's
    env is wrapped in, 1 without one): the model sees the last K (normalised) observations of each sub-env,
    oldest first, as SB3's VecFrameStack feeds it in training. The policy keeps one stack per sub-env
    between calls: ``episode_start[i]`` true empties sub-env i's stack (zeros) before observation i goes in,
    as VecFrameStack does on a reset or a done. Pass ``episode_start`` (true on the first call and after each
    reset, as :func:`softpvtol_gym.baselines.evaluation.run_episodes` does); without it the first call starts every
    stack and later calls continue them.
    """

    def __init__(self, model, vecnorm=None, frame_stack: int | None = None, inference: str = "lean"):
        self.model = model
        self.vecnorm = vecnorm
        if frame_stack is None:
            wrapper = frame_stack_wrapper(model.get_env())
            frame_stack = 1 if wrapper is None else int(wrapper.stacked_obs.n_stack)
        if isinstance(frame_stack, bool) or not isinstance(frame_stack, int) or frame_stack < 1:
            raise ValueError(f"frame_stack must be an integer >= 1, got {frame_stack!r}")
        if inference not in INFERENCE:
            raise ValueError(f"inference must be one of {list(INFERENCE)}, got {inference!r}")
        self.frame_stack = frame_stack
        self.inference = inference
        if inference == "torch" and is_zero_at_zero(model.policy):
            model.policy.set_zero_error(vecnorm)  # a zero error as these statistics normalise it
        space = model.observation_space
        self._stack = ObservationStack(frame_stack, int(space.shape[-1]), space.dtype)
        #: the lean path (None with inference="torch")
        self.lean = LeanMLPPolicy.from_sb3(model, vecnorm, frame_stack) if inference == "lean" else None

    def reset_stack(self) -> None:
        """Forget the stacked observations (the next call starts every sub-env's stack afresh)."""
        self._stack.reset()
        if self.lean is not None:
            self.lean.reset_stack()

    def stacked(self, obs: np.ndarray, episode_start) -> np.ndarray:
        """The torch path's model input for normalised observations ``obs`` (n_envs, obs_dim): the per-sub-env
        stack shifted by one observation, emptied where ``episode_start`` is true, with ``obs`` last."""
        return self._stack.push(obs, episode_start)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        if self.lean is not None:
            return self.lean.predict(observation, state, episode_start, deterministic)
        obs = checked_observations(observation, self._stack.width // self._stack.k)
        if self.vecnorm is not None and self.vecnorm.norm_obs:
            obs = self.vecnorm.normalize_obs(obs)
        if self.frame_stack > 1:  # (one observation (obs_dim,): a batch of one sub-env)
            single = obs.ndim == 1
            actions = self._policy_predict(self.stacked(obs.reshape(1, -1) if single else obs, episode_start),
                                           deterministic)
            return (actions[0] if single else actions), state
        return self._policy_predict(obs, deterministic), state

    def _policy_predict(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        """SB3's ``BasePolicy.predict`` (what ``model.predict`` calls) for the Box observations and actions of
        this env, without its ``set_training_mode(False)`` on every call (a walk over every torch module: a fifth
        of a periodic evaluation's time); the same calls otherwise, so the same actions."""
        import torch

        policy = self.model.policy
        if policy.training:
            policy.set_training_mode(False)
        obs_tensor, vectorized = policy.obs_to_tensor(obs)
        with torch.no_grad():
            actions = policy._predict(obs_tensor, deterministic=deterministic)
        actions = actions.cpu().numpy().reshape((-1, *policy.action_space.shape))
        if policy.squash_output:
            actions = policy.unscale_action(actions)
        else:
            actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
        return actions if vectorized else actions.squeeze(axis=0)

    @classmethod
    def load(cls, path: Path, trust_pickle: bool = False, inference: str = "lean") -> tuple[LearnedPolicy, RunConfig]:
        """Load from a run directory, a checkpoint directory or a file in one (``model.safetensors``), in the
        safe format (nothing is unpickled). ``trust_pickle=True`` also accepts pickle-based files (an SB3
        ``model.zip``, ``vecnormalize.pkl``: they can run code) where no safe checkpoint is found, with a
        warning. ``inference``: ``"lean"`` or ``"torch"`` (the class docstring)."""
        try:
            folder = find_checkpoint(path)
        except CheckpointError:
            if not trust_pickle:
                raise
            model, vecnorm, config = load_pickled(Path(path))
            return cls(model, vecnorm, frame_stack=frame_stack(config.hyperparams), inference=inference), config
        model, vecnorm, config, _ = load_folder(folder)
        return cls(model, vecnorm, inference=inference), config
