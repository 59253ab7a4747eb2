"""Train an SB3 agent on the native vector env: checkpoints, exact resume, periodic evaluation.

:func:`train` is what ``train.py`` and the leaderboard jobs call. A run directory holds

    config.yaml            the RunConfig (hyperparameters after CLI overrides, and the overrides)
    checkpoints/           atomic checkpoints (see :mod:`baselines.checkpoints`), the newest two kept
    tb/                    TensorBoard logs (``tensorboard --logdir <run>/tb``)
    evaluations.json       periodic evaluations on held-out seeded episodes
    model.zip, vecnormalize.pkl   the final model and normalisation statistics
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from .checkpoints import (
    CONFIG_FILE,
    MODEL_FILE,
    REPLAY_FILE,
    VECNORM_FILE,
    latest_checkpoint,
    load_resume_state,
    restore_rng,
    save_checkpoint,
)
from .config import ConfigError, RunConfig, algo_kwargs
from .evaluation import EVAL_SEED_OFFSET, run_episodes, summarize

EVALUATIONS_FILE = "evaluations.json"


class LearnedPolicy:
    """An SB3 model plus its observation normalisation, with SB3's ``predict`` on raw observations."""

    def __init__(self, model, vecnorm=None):
        self.model = model
        self.vecnorm = vecnorm

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(observation, dtype=np.float32)
        if self.vecnorm is not None and self.vecnorm.norm_obs:
            obs = self.vecnorm.normalize_obs(obs)
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)

    @classmethod
    def load(cls, path: Path) -> tuple[LearnedPolicy, RunConfig]:
        """Load from a run directory, a checkpoint directory or a ``model.zip`` next to its
        ``vecnormalize.pkl`` and ``config.yaml``."""
        path = Path(path)
        if path.is_file() and path.suffix == ".zip":
            folder, model_path = path.parent, path
        elif path.is_dir():
            folder, model_path = path, path / MODEL_FILE
            if not model_path.is_file():
                ck = latest_checkpoint(path)
                if ck is None:
                    raise FileNotFoundError(f"no {MODEL_FILE} and no checkpoint in {path}")
                folder, model_path = ck, ck / MODEL_FILE
        else:
            raise FileNotFoundError(f"checkpoint {path} does not exist (expected a run directory, a checkpoint "
                                    f"directory or a model.zip)")
        config_path = folder / CONFIG_FILE
        if not config_path.is_file():
            config_path = folder.parent / CONFIG_FILE
        config = RunConfig.load(config_path)
        algo_cls = _algo_class(config.algo)
        model = algo_cls.load(model_path, device="cpu")
        vecnorm = None
        if (folder / VECNORM_FILE).is_file():
            from stable_baselines3.common.vec_env import VecNormalize

            vecnorm = VecNormalize.load(str(folder / VECNORM_FILE), _dummy_venv(config))
            vecnorm.training = False
            vecnorm.norm_reward = False
        return cls(model, vecnorm), config


def _algo_class(algo: str):
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[algo]


def _dummy_venv(config: RunConfig):
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    return SoftPVTOLSB3VecEnv(num_envs=1, **config.env_kwargs())


def _make_env(config: RunConfig):
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    return SoftPVTOLSB3VecEnv(num_envs=config.n_envs, **config.env_kwargs())


def _callbacks(run_dir: Path, config: RunConfig, vecnorm, start_step: int):
    from stable_baselines3.common.callbacks import BaseCallback

    class CheckpointAndEval(BaseCallback):
        """At rollout boundaries (after an update, before the next rollout): checkpoint every
        ``checkpoint_freq`` steps and evaluate every ``eval_freq`` steps."""

        def __init__(self):
            super().__init__()
            self.next_ckpt = (start_step // config.checkpoint_freq + 1) * config.checkpoint_freq
            self.next_eval = (start_step // config.eval_freq + 1) * config.eval_freq
            self.history = _load_evaluations(run_dir, max_step=start_step)

        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:
            step = self.model.num_timesteps
            if config.eval_episodes and step >= self.next_eval:
                self.next_eval = (step // config.eval_freq + 1) * config.eval_freq
                self._evaluate(step)
            if step >= self.next_ckpt:
                self.next_ckpt = (step // config.checkpoint_freq + 1) * config.checkpoint_freq
                save_checkpoint(run_dir, self.model, vecnorm, config)

        def _on_training_end(self) -> None:
            step = self.model.num_timesteps
            if config.eval_episodes and (not self.history or self.history[-1]["step"] != step):
                self._evaluate(step)

        def _evaluate(self, step: int) -> None:
            policy = LearnedPolicy(self.model, vecnorm)
            eps = run_episodes(policy, config.action_mode, config.task, config.tier, config.eval_episodes,
                               EVAL_SEED_OFFSET + config.seed)
            s = summarize(eps)
            for key in ("mean_return", "mean_rms_position_error", "crash_rate"):
                self.logger.record(f"eval/{key}", s[key])
            self.history.append({"step": int(step), **s})
            _write_json_atomic(run_dir / EVALUATIONS_FILE, self.history)

    return CheckpointAndEval()


def train(config: RunConfig, run_dir: Path, resume: bool = False, progress_bar: bool = False,
          verbose: int = 0) -> dict:
    """Train (or resume) a run in ``run_dir``; returns ``{"model": ..., "vecnorm": ..., "seconds": ...}``.

    Fresh runs refuse a ``run_dir`` that already holds a run (nothing is overwritten). ``resume=True``
    continues from the newest checkpoint with the saved config (``config`` must then match it in
    algo, action mode, task, tier, seed and n_envs) up to ``config.timesteps``.
    """
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    run_dir = Path(run_dir)
    algo_cls = _algo_class(config.algo)
    hp = config.hyperparams
    norm = hp.get("normalize") or None
    ckpt = latest_checkpoint(run_dir) if resume else None
    if resume and ckpt is None:
        raise ConfigError(f"--resume: no checkpoint in {run_dir / 'checkpoints'} (start without --resume)")
    if not resume and ((run_dir / CONFIG_FILE).exists() or (run_dir / MODEL_FILE).exists()):
        raise ConfigError(f"{run_dir} already holds a run; pass --resume to continue it or choose another --out "
                          f"(nothing was overwritten)")
    torch.set_num_threads(int(os.environ.get("SOFTPVTOL_TORCH_THREADS", "1")))
    run_dir.mkdir(parents=True, exist_ok=True)
    if ckpt is None:
        config.save(run_dir / CONFIG_FILE)
        env = _make_env(config)
        env.seed(config.seed)
        vecnorm = VecNormalize(env, **norm) if norm else None
        model = algo_cls(hp.get("policy", "MlpPolicy"), vecnorm or env, seed=config.seed, device="cpu",
                         verbose=verbose, tensorboard_log=str(run_dir / "tb"), **algo_kwargs(hp))
        start = 0
    else:
        saved = RunConfig.load(ckpt / CONFIG_FILE)
        for key in ("algo", "action_mode", "task", "tier", "seed", "n_envs", "hyperparams"):
            if getattr(saved, key) != getattr(config, key):
                raise ConfigError(f"--resume: {key} of the checkpoint is {getattr(saved, key)!r}, the command asks "
                                  f"for {getattr(config, key)!r}; resume with the run's own settings")
        state = load_resume_state(ckpt)
        from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

        env = SoftPVTOLSB3VecEnv(vector_env=state["vector_env"])
        vecnorm = None
        if norm:
            vecnorm = VecNormalize.load(str(ckpt / VECNORM_FILE), env)
            vecnorm.returns = state["vecnormalize_returns"].copy()
        model = algo_cls.load(ckpt / MODEL_FILE, env=vecnorm or env, device="cpu", force_reset=False,
                              tensorboard_log=str(run_dir / "tb"), verbose=verbose)
        if (ckpt / REPLAY_FILE).is_file():
            model.load_replay_buffer(ckpt / REPLAY_FILE)
        restore_rng(state)
        start = int(state["num_timesteps"])
        config.save(run_dir / CONFIG_FILE)
    remaining = config.timesteps - start
    t0 = time.perf_counter()
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=_callbacks(run_dir, config, vecnorm, start),
                    reset_num_timesteps=ckpt is None, tb_log_name=config.algo.upper(), progress_bar=progress_bar)
    seconds = time.perf_counter() - t0
    model.save(run_dir / MODEL_FILE)
    if vecnorm is not None:
        vecnorm.save(str(run_dir / VECNORM_FILE))
    return {"model": model, "vecnorm": vecnorm, "seconds": seconds}


def _load_evaluations(run_dir: Path, max_step: int) -> list[dict]:
    path = run_dir / EVALUATIONS_FILE
    if not path.is_file():
        return []
    return [e for e in json.loads(path.read_text()) if e["step"] <= max_step]


def _write_json_atomic(path: Path, data) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)
