"""Fine-tuning from a student: PPO started from another run's policy (``train --init-from RUN``), with an
imitation term toward a teacher whose weight decays (``--bc-weight``, ``--bc-decay-steps``, ``--bc-teacher``).

Starting point. The new run's policy gets every weight of the source run's policy (actor, value net, log-std),
and its VecNormalize the source's observation statistics, weighted as :data:`FROZEN_COUNT` samples: VecNormalize
updates its running mean with each batch in proportion to the batch's share of the count, so the statistics
the student was fitted with stay as they were (a shift of them would move every input of the network).

Imitation term. A PPO update that follows noisy returns can first undo what imitation learned. After each
PPO update (at the next rollout's start, and at the end of training) the actor takes ``epochs`` passes of
gradient steps on the mean squared error between its mean action and the teacher's,

    mean((mu(obs) - a_teacher(obs))^2)    with Adam at the learning rate  w(t) * lr0,
    w(t) = w0 * max(0, 1 - t / decay_steps),

(a fresh Adam each time, mini-batches of the PPO batch size, lr0 the run's initial learning rate: Adam is
invariant to a loss's scale, so the weight scales the step) over the observations of the rollout just trained
on, labelled by the teacher as it ran beside the policy (:mod:`.teachers`: the same observations, step by
step, so a teacher with memory keeps it). Once w reaches 0
the term stops and the teacher is no longer asked. The weight is the imitation term's (the DAPG / "BC
regulariser" form of fine-tuning with demonstrations); a resumed run restarts the teacher's memory of the
running episodes and the term's optimizer, so it is not bit for bit the uninterrupted run.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.load import load_folder
from softpvtol_gym.baselines.checkpoints.store import find_checkpoint
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.teachers import teacher_policy

__all__ = ["FROZEN_COUNT", "init_from_run", "source_overrides", "imitation_callback", "imitation_weight",
           "actor_parameters", "action_gap"]

#: the sample count given to the source run's observation statistics (they barely move during fine-tuning)
FROZEN_COUNT = 1e12


def init_from_run(model, vecnorm, source: Path) -> RunConfig:
    """Fill ``model``'s policy and ``vecnorm``'s observation statistics from the run in ``source`` (loaded
    without unpickling); the source's config is returned. A ConfigError when the two policies differ in
    shape (another action mode, observation or network) or one has normalisation and the other not."""
    import torch

    src_model, src_vecnorm, src_config, _ = load_folder(find_checkpoint(Path(source)))
    theirs, ours = src_model.policy.state_dict(), model.policy.state_dict()
    shapes = {k: tuple(v.shape) for k, v in theirs.items()}
    if shapes != {k: tuple(v.shape) for k, v in ours.items()}:
        raise ConfigError(f"--init-from {source}: its policy ({_describe(shapes)}) does not have this run's shape "
                          f"({_describe({k: tuple(v.shape) for k, v in ours.items()})}); fine-tune it with its own "
                          f"action mode, env options and policy_kwargs")
    with torch.no_grad():
        model.policy.load_state_dict(theirs)
    if (src_vecnorm is None) != (vecnorm is None):
        raise ConfigError(f"--init-from {source}: normalisation {'on' if src_vecnorm else 'off'} there, "
                          f"{'on' if vecnorm else 'off'} here; pass the same normalize hyperparameter")
    if vecnorm is not None:
        vecnorm.obs_rms.mean = np.array(src_vecnorm.obs_rms.mean, dtype=np.float64)
        vecnorm.obs_rms.var = np.array(src_vecnorm.obs_rms.var, dtype=np.float64)
        vecnorm.obs_rms.count = FROZEN_COUNT
    return src_config


def source_overrides(source: RunConfig | None) -> list[str]:
    """The hyperparameter overrides that give a fine-tuning run the network, normalisation and frame stack of the
    run it starts from (its config ``source``; None: none)."""
    if source is None:
        return []
    hp = source.hyperparams
    out = [f"normalize={json.dumps(hp.get('normalize', False))}"]
    if "policy_kwargs" in hp:
        out.append(f"policy_kwargs={hp['policy_kwargs']}")
    if "frame_stack" in hp:
        out.append(f"frame_stack={int(hp['frame_stack'])}")
    return out


def actor_parameters(policy) -> list:
    """The parameters of an SB3 actor-critic policy that make its mean action (the value net and the
    log-std left out): what imitation fits."""
    return [p for name, p in policy.named_parameters()
            if not name.startswith(("value_net", "mlp_extractor.value_net")) and name != "log_std"]


def action_gap(policy, obs, actions, weights=None, channel_weights=None):
    """The (weighted) mean squared error between ``policy``'s mean actions at the normalised observations
    ``obs`` (n, d) and ``actions`` (n, 4), torch tensors; ``weights`` (n,) per sample and ``channel_weights`` (4,)
    per action channel, each None for 1."""
    err = (policy.get_distribution(obs).distribution.mean - actions) ** 2
    if channel_weights is not None:
        err = err * channel_weights
    return (err if weights is None else weights[:, None] * err).mean()


def _describe(shapes: dict) -> str:
    first = next((v for k, v in shapes.items() if k.endswith("weight")), None)
    return f"{len(shapes)} tensors, first layer {first}"


def imitation_weight(spec: dict, step: int) -> float:
    """w(t) of the imitation term at training step ``step`` (module docstring)."""
    return float(spec["weight"]) * max(0.0, 1.0 - step / float(spec["decay_steps"]))


def imitation_callback(config: RunConfig, vecnorm):
    """The SB3 callback of the run's imitation term (``config.imitation``: teacher, weight, decay_steps,
    epochs)."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    spec = config.imitation
    if vecnorm is None:
        raise ConfigError("the imitation term needs the run's observation normalisation (normalize: true): the "
                          "teacher reads the raw observations VecNormalize keeps")

    class ImitationTerm(BaseCallback):
        def __init__(self):
            super().__init__()
            self.teacher = teacher_policy(spec["teacher"], config.task, config.env_options)
            self.obs, self.labels = [], []
            self.starts = None
            #: per imitation phase: step, weight, the gap to the teacher's actions before and after it
            self.history = []

        def _label(self, model_obs) -> None:
            """The teacher's label of the raw observation the policy acts on next, stored with ``model_obs``, what
            the policy sees (normalised; with a frame stack, the stack: the same as VecNormalize's output without)."""
            raw = vecnorm.get_original_obs()
            label, _ = self.teacher.predict(raw, episode_start=self.starts, deterministic=True)
            self.obs.append(np.asarray(model_obs, dtype=np.float32).copy())
            self.labels.append(np.asarray(label, np.float32))

        def _active(self) -> bool:
            return imitation_weight(spec, self.model.num_timesteps) > 0

        def _on_training_start(self) -> None:
            self.starts = np.ones(self.training_env.num_envs, bool)

        def _on_rollout_start(self) -> None:
            if self.obs:
                self._imitate()
            self.obs, self.labels = [], []
            if self._active():
                self._label(self.model._last_obs)  # the observation the rollout's first step acts on

        def _on_training_end(self) -> None:
            if self.obs:  # the last rollout's term (no next rollout starts)
                self._imitate()
            self.obs, self.labels = [], []

        def _on_step(self) -> bool:
            if self.obs:
                self.starts = np.asarray(self.locals["dones"], bool)
                if len(self.obs) < self.model.n_steps:
                    self._label(self.locals["new_obs"])
            return True

        def _imitate(self) -> None:
            w = imitation_weight(spec, self.model.num_timesteps)
            if w <= 0:
                return
            policy = self.model.policy
            x = torch.as_tensor(np.concatenate(self.obs), device=policy.device)
            y = torch.as_tensor(np.concatenate(self.labels), device=policy.device)
            optimizer = torch.optim.Adam(actor_parameters(policy), lr=w * float(self.model.lr_schedule(1.0)))
            batch = int(self.model.batch_size)
            before = self._gap(x, y)
            for _ in range(int(spec["epochs"])):
                order = torch.randperm(len(x))
                for b in range(0, len(x), batch):
                    idx = order[b:b + batch]
                    loss = action_gap(policy, x[idx], y[idx])
                    optimizer.zero_grad()
                    loss.backward()
                    optimizer.step()
            entry = {"step": int(self.model.num_timesteps), "weight": w, "gap_before": before,
                     "gap_after": self._gap(x, y)}
            self.history.append(entry)
            for key in ("weight", "gap_before", "gap_after"):
                self.logger.record(f"imitation/{key}", entry[key])

        def _gap(self, x, y) -> float:
            """The mean squared error between the policy's mean actions and the teacher's."""
            with torch.no_grad():
                return float(action_gap(self.model.policy, x, y))

    return ImitationTerm()
