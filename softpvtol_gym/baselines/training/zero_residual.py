"""ZeroAtZeroPolicy: a PPO actor-critic policy whose action is exactly zero at zero tracking error.

A residual policy corrects an analytic loop that already holds the reference; a correction that is not zero there
pushes the robot off it (a learned residual measured at zero error still pushed 9 % of the weight vertically and
flipped sign every step). This policy's action mean is

    a(s, e) = g(s, e) - g(s, 0)

with g the actor MLP (SB3's ``mlp_extractor.policy_net`` then ``action_net``), e the tracking errors of the
observation, s the rest of it, and g(s, 0) the same network on the observation with its errors set to zero. So the
correction is exactly 0 wherever e = 0, whatever s, and smooth (g is). The errors are the observation's entries
:func:`error_entries`: the position and attitude errors (x - x_ref, z - z_ref, theta - theta_ref) and, with
``observe_error_integral=True``, their integrals; the velocities are part of s.

The network sees VecNormalize's normalised observation, in which a zero error is the value VecNormalize gives a raw
0 (``clip((0 - mean) / sqrt(var + epsilon))`` as float32): the policy holds those values
(:meth:`ZeroAtZeroPolicy.set_zero_error`), set from the run's statistics at the start of each rollout in training
(:func:`zero_error_callback`) and when a run is loaded; with the very arithmetic of VecNormalize, so that an
observation with zero errors gives the action 0 to the last bit. A policy class (``policy: ZeroAtZeroPolicy`` in a
run's hyperparameters) of a Gaussian PPO/A2C policy on a flat observation, without gSDE and without a frame stack;
the safe checkpoint format rebuilds it from the run's configuration like an ``MlpPolicy`` (it adds no weights).
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

from softpvtol_gym.envs.observation import N_ERROR_INTEGRALS, OBS_DIM, OBSERVATION

#: the hyperparameter value (``policy: ZeroAtZeroPolicy``) that selects this policy class
NAME = "ZeroAtZeroPolicy"


def error_entries(obs_dim: int) -> np.ndarray:
    """The tracking-error entries of an observation of ``obs_dim`` entries: the position and attitude errors, and
    their integrals where the observation holds them (``OBS_DIM + 3`` entries). ValueError for another size."""
    at = OBSERVATION.at
    errors = [at.e_pos, at.e_pos + 1, at.e_theta]  # x - x_ref, z - z_ref, theta - theta_ref
    if obs_dim == OBS_DIM:
        return np.asarray(errors, dtype=np.int64)
    if obs_dim == OBS_DIM + N_ERROR_INTEGRALS:
        return np.asarray([*errors, *range(OBS_DIM, OBS_DIM + N_ERROR_INTEGRALS)], dtype=np.int64)
    raise ValueError(f"{NAME} takes the env's observation of {OBS_DIM} entries ({OBS_DIM + N_ERROR_INTEGRALS} with "
                     f"observe_error_integral=True), got {obs_dim} entries (a frame stack is not supported)")


def zero_error_values(index: np.ndarray, vecnorm=None) -> np.ndarray:
    """The normalised observation's value at entries ``index`` for a raw 0 (float32), with VecNormalize's own
    arithmetic (``vecnorm`` None, or not normalising observations: 0)."""
    if vecnorm is None or not vecnorm.norm_obs:
        return np.zeros(len(index), dtype=np.float32)
    rms = vecnorm.obs_rms
    raw = np.zeros((1, rms.mean.shape[0]), dtype=np.float32)
    normed = np.clip((raw - rms.mean) / np.sqrt(rms.var + vecnorm.epsilon), -vecnorm.clip_obs, vecnorm.clip_obs)
    return normed.astype(np.float32)[0, index]


class _ZeroAtZeroExtractor(MlpExtractor):
    """SB3's MlpExtractor whose actor latent is the pair (h(f), h(f with the errors at zero)), concatenated."""

    def __init__(self, feature_dim: int, *args, **kwargs):
        super().__init__(feature_dim, *args, **kwargs)
        index = torch.as_tensor(error_entries(feature_dim))
        self.register_buffer("error_index", index, persistent=False)
        self.register_buffer("zero_error", torch.zeros(len(index)), persistent=False)

    def at_zero_error(self, features: torch.Tensor) -> torch.Tensor:
        out = features.clone()
        out[..., self.error_index] = self.zero_error.to(features.dtype)
        return out

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.policy_net(features), self.policy_net(self.at_zero_error(features))], dim=-1)


class ZeroAtZeroPolicy(ActorCriticPolicy):
    """SB3's ActorCriticPolicy (MlpPolicy) with the action mean g(s, e) - g(s, 0) (module docstring)."""

    def __init__(self, observation_space, action_space, lr_schedule, *args, **kwargs):
        if kwargs.get("use_sde"):
            raise ValueError(f"{NAME} has a Gaussian action with a state-independent std: use_sde must be False")
        if len(observation_space.shape) != 1:
            raise ValueError(f"{NAME} takes a flat observation, got shape {observation_space.shape}")
        error_entries(observation_space.shape[0])  # the env's observation, or a clear error
        super().__init__(observation_space, action_space, lr_schedule, *args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = _ZeroAtZeroExtractor(self.features_dim, net_arch=self.net_arch,
                                                  activation_fn=self.activation_fn, device=self.device)

    def _get_action_dist_from_latent(self, latent_pi: torch.Tensor):
        at, zero = latent_pi.chunk(2, dim=-1)
        mean_actions = self.action_net(at) - self.action_net(zero)
        if not isinstance(self.action_dist, DiagGaussianDistribution):
            raise ValueError(f"{NAME} acts on a Box action (a Gaussian), got {type(self.action_dist).__name__}")
        return self.action_dist.proba_distribution(mean_actions, self.log_std)

    @property
    def error_index(self) -> np.ndarray:
        """The observation's error entries (:func:`error_entries`)."""
        return self.mlp_extractor.error_index.cpu().numpy()

    def set_zero_error(self, vecnorm=None) -> None:
        """Set the normalised values of a zero error from the run's VecNormalize (None: no normalisation)."""
        values = zero_error_values(self.error_index, vecnorm)
        self.mlp_extractor.zero_error.copy_(torch.as_tensor(values))


def zero_error_callback(vecnorm):
    """An SB3 callback that sets the policy's zero-error values from ``vecnorm``'s statistics at the start of each
    rollout (the rollout and the update after it then use the same values)."""

    class ZeroErrorCallback(BaseCallback):
        def _on_rollout_start(self) -> None:
            self.model.policy.set_zero_error(vecnorm)

        def _on_step(self) -> bool:
            return True

    return ZeroErrorCallback()
