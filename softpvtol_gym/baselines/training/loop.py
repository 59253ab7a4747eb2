"""Train an SB3 agent on the native vector env: checkpoints, exact resume, periodic evaluation.

:func:`train` is what ``train.py`` and the leaderboard jobs call. A run directory holds

    config.yaml            the RunConfig (hyperparameters after CLI overrides, and the overrides)
    checkpoints/           atomic checkpoints (see :mod:`softpvtol_gym.baselines.checkpoints`), the newest two kept
    tb/                    TensorBoard logs (``tensorboard --logdir <run>/tb``)
    evaluations.json       periodic evaluations on held-out seeded episodes
    model.safetensors, model.json, vecnormalize.json, checkpoint.json   the final model (a checkpoint
                           folder: the manifest checkpoint.json is written last and marks the run finished)
    .softpvtol.lock        held while a process works on the run (a second one gets exit 2)
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

from softpvtol_gym.baselines.checkpoints.load import load_folder, load_for_resume
from softpvtol_gym.baselines.checkpoints.manifest import CONFIG_FILE, MANIFEST_FILE, read_manifest, read_verified
from softpvtol_gym.baselines.checkpoints.store import (
    checkpoint_candidates,
    clean_run_dir,
    legacy_files,
    save_checkpoint,
    warn,
    write_model_files,
)
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, run_episodes, summarize
from softpvtol_gym.baselines.training.imitation import imitation_callback, init_from_run
from softpvtol_gym.baselines.training.lean import is_zero_at_zero
from softpvtol_gym.baselines.training.models import (
    algo_class,
    build_model,
    make_env,
    make_vecnorm,
    resolve_device,
    stack_frames,
)
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.locks import DirectoryLock
from softpvtol_gym.baselines.util.safe_load import loads_json

EVALUATIONS_FILE = "evaluations.json"
#: what a command may change on --resume (everything else must match the run's saved config)
RESUME_MAY_CHANGE = ("timesteps", "overrides", "checkpoint_freq", "eval_freq", "eval_episodes")



def _algo_class(algo: str):  # kept for callers of earlier versions
    return algo_class(algo)


class _ProgressBar:
    """A progress bar over the env steps that ``learn`` will really run (PPO trains whole rollouts), which
    therefore ends at its total."""

    @staticmethod
    def planned_steps(model, remaining: int) -> int:
        chunk = model.n_envs
        if hasattr(model, "n_steps") and hasattr(model, "rollout_buffer"):  # on-policy: whole rollouts
            chunk = model.n_steps * model.n_envs
        elif getattr(getattr(model, "train_freq", None), "unit", None) is not None:
            tf = model.train_freq
            if tf.unit.value == "step":
                chunk = tf.frequency * model.n_envs
        return int(math.ceil(remaining / chunk) * chunk)

    @staticmethod
    def callback(total: int):
        from stable_baselines3.common.callbacks import BaseCallback

        class ProgressBar(BaseCallback):
            def __init__(self):
                super().__init__()
                self.total, self.n, self.pbar = total, 0, None

            def _on_training_start(self) -> None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # tqdm.rich is "experimental"
                    from tqdm.rich import tqdm

                    self.pbar = tqdm(total=self.total, unit="step")

            def _on_step(self) -> bool:
                inc = min(self.training_env.num_envs, self.total - self.n)
                if inc > 0:
                    self.n += inc
                    self.pbar.update(inc)
                return True

            def _on_training_end(self) -> None:
                self.pbar.refresh()
                self.pbar.close()

        return ProgressBar()


def _callbacks(run_dir: Path, config: RunConfig, vecnorm, start_step: int):
    from stable_baselines3.common.callbacks import BaseCallback

    class CheckpointAndEval(BaseCallback):
        """At rollout boundaries (after an update, before the next rollout): checkpoint every
        ``checkpoint_freq`` steps and evaluate every ``eval_freq`` steps (and the untrained policy at step 0
        of a fresh run)."""

        def __init__(self):
            super().__init__()
            self.next_ckpt = (start_step // config.checkpoint_freq + 1) * config.checkpoint_freq
            self.next_eval = (start_step // config.eval_freq + 1) * config.eval_freq
            self.history = _load_evaluations(run_dir, max_step=start_step)
            self.started = time.perf_counter()

        def _on_training_start(self) -> None:
            self.started = time.perf_counter()
            if config.eval_episodes and start_step == 0 and not self.history:
                self._evaluate(0)  # the untrained policy: where the learning curve starts

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
                               EVAL_SEED_OFFSET + config.seed, env_kwargs=config.eval_env_kwargs())
            s = summarize(eps)
            for key in ("mean_return", "mean_rms_position_error", "crash_rate"):
                self.logger.record(f"eval/{key}", s[key])
            # train_seconds: since this process started training (a resumed run counts from its resume);
            # wall_time: the end of this evaluation, in seconds since the epoch (for timing from outside)
            self.history.append({"step": int(step), **s, "train_seconds": round(time.perf_counter() - self.started, 3),
                                 "wall_time": round(time.time(), 3)})
            atomic_write_text(run_dir / EVALUATIONS_FILE, json.dumps(self.history, indent=2))

    return CheckpointAndEval()


def _set_start_error_scale(venv, scale: float) -> None:
    """The native vector env's starting-error scale for every later reset (through the SB3 wrappers)."""
    venv.env_method("set_start_error_scale", scale, indices=[0])


def _curriculum_callback(config: RunConfig):
    """At every rollout's start: the curriculum's starting-error scale (RunConfig.start_error_curriculum)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class StartErrorCurriculum(BaseCallback):
        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:
            scale = config.start_error_scale_at(self.model.num_timesteps)
            _set_start_error_scale(self.training_env, scale)
            self.logger.record("train/start_error_scale", scale)

    return StartErrorCurriculum()


def finished_run(run_dir: Path) -> dict | None:
    """The verified manifest of a run directory's final model, or None if the run is not finished."""
    run_dir = Path(run_dir)
    if not (run_dir / MANIFEST_FILE).is_file():
        return None
    try:
        manifest = read_manifest(run_dir)
        for name in manifest["files"]:
            read_verified(run_dir, manifest, name)
    except CheckpointError as exc:
        warn(f"{exc}; the run is treated as unfinished")
        return None
    return manifest


def _check_same_run(saved: RunConfig, config: RunConfig, where: str) -> None:
    for key in ("algo", "action_mode", "task", "tier", "seed", "n_envs", "hyperparams", "env_options",
                "train_env_options", "start_error_curriculum"):
        if getattr(saved, key) != getattr(config, key):
            raise ConfigError(f"--resume: {key} of {where} is {getattr(saved, key)!r}, the command asks for "
                              f"{getattr(config, key)!r}; resume with the run's own settings (or leave the option "
                              f"out)")


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def torch_threads() -> int:
    """``SOFTPVTOL_TORCH_THREADS`` (default 1), checked."""
    raw = os.environ.get("SOFTPVTOL_TORCH_THREADS", "1")
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if not 1 <= n <= 1024:
        raise ConfigError(f"SOFTPVTOL_TORCH_THREADS must be an integer in [1, 1024], got {raw!r}")
    return n


def prepare(config: RunConfig, run_dir: Path, verbose: int = 0, device: str = "cpu") -> tuple:
    """The env, VecNormalize and model of a fresh run, built in memory (the policy on ``device``: "auto",
    "cpu" or "cuda"; the env on the CPU): everything stable-baselines3 would refuse is refused here
    (ConfigError), before anything is written."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError(f"run directory {run_dir} is a file; choose a directory for --out")
    import torch

    # before the model is built: its initial weights (orthogonal initialisation) depend on torch's thread
    # count, which would otherwise be the machine's core count here (train() sets the same count again)
    torch.set_num_threads(torch_threads())
    device = resolve_device(device)
    env = make_env(config)
    vecnorm = make_vecnorm(config, env)
    model = build_model(config, stack_frames(config, vecnorm or env), tensorboard_log=str(run_dir / "tb"),
                        verbose=verbose, device=device)
    if config.init_from is not None:  # a fine-tuning run starts from another run's policy (a resume then loads its own)
        init_from_run(model, vecnorm, Path(config.init_from))
    return env, vecnorm, model


def train(config: RunConfig, run_dir: Path, resume: bool = False, progress_bar: bool = False,
          verbose: int = 0, prepared: tuple | None = None, device: str = "cpu") -> dict:
    """Train (or resume) a run in ``run_dir``; returns ``{"model", "vecnorm", "seconds", "status"}`` with
    status ``"trained"`` or ``"finished"`` (``resume=True`` on a run already trained to ``config.timesteps``:
    nothing is trained, the final model is loaded).

    Before anything is written, the env and the model are built in memory (so that bad hyperparameters
    fail with a ConfigError and leave nothing behind) and the run directory is locked (a second process
    gets a ConfigError naming the holder). Fresh runs refuse a ``run_dir`` that holds a checkpoint or a
    finished model (nothing is overwritten); a directory without a complete checkpoint (a run killed
    before its first one) starts over. ``resume=True`` continues from the newest checkpoint that verifies
    (falling back to the previous one, with a warning), with the saved config (``config`` must match it
    in algo, action mode, task, tier, seed, n_envs, hyperparameters and env options) up to ``config.timesteps``.
    ``device`` ("auto", "cpu", "cuda"): where the policy trains (the env steps on the CPU); a run may be
    resumed on another device.
    """
    import torch

    run_dir = Path(run_dir)
    torch.set_num_threads(torch_threads())
    device = resolve_device(device)
    env, vecnorm, model = prepared if prepared is not None else prepare(config, run_dir, verbose, device)
    with DirectoryLock(run_dir, "run directory"):
        clean_run_dir(run_dir)
        finished = finished_run(run_dir)
        candidates = checkpoint_candidates(run_dir)
        legacy = legacy_files(run_dir) + [f"{c.name}/{n}" for c in candidates for n in legacy_files(c)]
        if not resume:
            if finished is not None or candidates or legacy:
                raise ConfigError(f"{run_dir} already holds a run; pass --resume to continue it or choose another "
                                  f"--out (nothing was overwritten)")
            if (run_dir / CONFIG_FILE).exists():
                _say(f"{run_dir} holds a run that never reached its first checkpoint: starting it over")
        restore_rng = None
        start = 0
        if resume:
            if finished is not None:
                try:
                    saved = RunConfig.load(run_dir / CONFIG_FILE)
                except ConfigError:
                    saved = None
                if saved is not None:
                    _check_same_run(saved, config, f"the run in {run_dir}")
                if finished["num_timesteps"] >= config.timesteps:
                    model, vecnorm, _, _ = load_folder(run_dir, device=device)
                    return {"model": model, "vecnorm": vecnorm, "seconds": 0.0, "status": "finished",
                            "num_timesteps": finished["num_timesteps"]}
            errors = []
            for cand in candidates:
                try:
                    saved = RunConfig.load(cand / CONFIG_FILE)
                except ConfigError as exc:
                    errors.append(str(exc))
                    warn(f"skipping a checkpoint: {exc}")
                    continue
                _check_same_run(saved, config, f"checkpoint {cand}")
                try:
                    model, vecnorm, restore_rng = load_for_resume(cand, config, run_dir, verbose=verbose,
                                                                  device=device)
                except CheckpointError as exc:
                    errors.append(str(exc))
                    warn(f"skipping a checkpoint: {exc}")
                    continue
                if errors:
                    warn(f"resuming from the previous checkpoint {cand}")
                start = int(model.num_timesteps)
                break
            else:
                if errors:
                    raise ConfigError(f"--resume: no checkpoint of {run_dir} is usable ({'; '.join(errors)}); "
                                      f"remove {run_dir / 'checkpoints'} to start the run over")
                if legacy:
                    raise ConfigError(f"--resume: {run_dir} holds only pickle-based checkpoint files of an earlier "
                                      f"version ({', '.join(legacy[:4])}), which this version does not load (they can "
                                      f"run code); start the run over in another --out")
                if (run_dir / CONFIG_FILE).exists():
                    _say(f"{run_dir} has no complete checkpoint yet (the run was stopped before its first one): "
                         f"starting from step 0")
        if finished is not None:  # continuing a finished run beyond its steps: it is unfinished until the end
            (run_dir / MANIFEST_FILE).unlink()
        config.save(run_dir / CONFIG_FILE)
        remaining = config.timesteps - start
        t0 = time.perf_counter()
        if remaining > 0:
            callbacks = [_callbacks(run_dir, config, vecnorm, start)]
            if config.imitation is not None:  # first: its step after an update comes before a checkpoint of it
                callbacks.insert(0, imitation_callback(config, vecnorm))
            if is_zero_at_zero(model.policy):  # the zero-error values of each rollout's statistics
                from softpvtol_gym.baselines.training.zero_residual import zero_error_callback

                callbacks.insert(0, zero_error_callback(vecnorm))
            if config.start_error_curriculum is not None:
                # the first rollout's starts too (SB3 resets the env before the callbacks run)
                _set_start_error_scale(model.get_env(), config.start_error_scale_at(start))
                callbacks.append(_curriculum_callback(config))
            planned = _ProgressBar.planned_steps(model, remaining)
            if progress_bar:
                if planned != remaining:
                    _say(f"{config.algo.upper()} trains whole rollouts: {planned:,} steps for the {remaining:,} asked")
                callbacks.append(_ProgressBar.callback(planned))
            if restore_rng is not None:
                restore_rng()
            model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=start == 0,
                        tb_log_name=config.algo.upper(), progress_bar=False)
        seconds = time.perf_counter() - t0
        save_checkpoint(run_dir, model, vecnorm, config)  # the end state: a longer --resume continues from it
        write_model_files(run_dir, model, vecnorm, config, "run")
    return {"model": model, "vecnorm": vecnorm, "seconds": seconds, "status": "trained",
            "num_timesteps": int(model.num_timesteps)}


def _load_evaluations(run_dir: Path, max_step: int) -> list[dict]:
    path = run_dir / EVALUATIONS_FILE
    if not path.is_file():
        return []
    try:
        data = loads_json(path.read_text(), str(path))
        return [e for e in data if isinstance(e, dict) and isinstance(e.get("step"), int) and e["step"] <= max_step]
    except (OSError, ValueError, TypeError):
        warn(f"{path} is unreadable; the periodic evaluations start a new list")
        return []
