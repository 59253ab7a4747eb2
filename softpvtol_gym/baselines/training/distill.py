"""Distillation: a student MLP learned from a teacher controller by behaviour cloning and DAgger.

The student is the actor of a stable-baselines3 PPO ``MlpPolicy`` on the actuators mode with the error
integrals observed (``observe_error_integral``: what makes an offset-free controller possible is part of the
observation, not a hidden state), so a distilled run is a run like any other: the same safe checkpoint
format, ``softpvtol evaluate RUN``, the lean inference path, the leaderboard, and PPO fine-tuning from it.

Rounds (Ross et al., "A reduction of imitation learning to no-regret online learning", 2011):

* round 0 (behaviour cloning): the teacher flies ``episodes`` seeded episodes per task and tier; every step's
  observation is stored with the teacher's action;
* round k >= 1 (DAgger): the student of round k - 1 flies new episodes and the teacher labels every
  observation the student visits (the teacher runs beside it on the same observations, so a teacher with
  memory, such as the integral loop or the MPC's disturbance estimate, keeps it along the student's path);
* after each round the student is fitted from the same initial weights to the aggregate of all rounds'
  data: VecNormalize's statistics are the aggregate's mean and variance, the actor (policy net and action
  net; the value net and log-std are left as built) minimises the mean squared error between its
  Gaussian's mean and the teacher's action with Adam, the learning rate decayed linearly to 0.

Every dataset is cached under ``<run>/datasets/`` (npz, loaded without pickle), so ``resume=True`` skips the
rounds already collected and refits deterministically (one torch thread, seeded), giving the run an
uninterrupted one gives. Seeds: collection episodes from ``seed * 10,000``, below the training seed limit;
the per-round evaluation on ``DISTILL_EVAL_SEED + 1,000 * seed`` on, disjoint from the leaderboard's test
and selection episodes. ``distill.json`` records the losses per epoch, the rounds' sample counts and the
student's and teacher's metrics per round.

Why not the ``imitation`` library: its BC and DAgger trainers wrap SB3 policies over gymnasium envs that
reset one episode at a time, and it pins its own ranges of gymnasium and stable-baselines3; the fit here is
a regression of a few dozen lines on arrays this package already produces in batches (the native vector
env), and keeping it here keeps the dependency list to the four the package names.
"""

from __future__ import annotations

import io
import json
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.store import write_model_files
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import TUNING_SEED, run_episodes, summarize
from softpvtol_gym.baselines.training.distill_config import EARLIER_DEFAULTS, DistillConfig
from softpvtol_gym.baselines.training.imitation import action_gap, actor_parameters
from softpvtol_gym.baselines.training.loop import prepare, torch_threads
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.training.teachers import (
    TEACHERS,
    collect,
    teacher_policy,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_bytes, atomic_write_text
from softpvtol_gym.baselines.util.locks import DirectoryLock
from softpvtol_gym.envs.observation import N_ERROR_INTEGRALS, OBS_DIM
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

__all__ = ["DistillConfig", "distill", "teacher_policy", "collect", "distill_table", "TEACHERS", "DISTILL_FILE"]

#: the record of a distilled run, next to its model files
DISTILL_FILE = "distill.json"
DATASET_DIR = "datasets"
#: the first seed of the per-round evaluation episodes (test episodes start at 1,000,000, selection at 2,000,000)
DISTILL_EVAL_SEED = TUNING_SEED


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _dataset_path(run_dir: Path, round_index: int, tier: str, task: str | None = None) -> Path:
    """A round's dataset on ``tier`` (and on ``task``, one of ``also_tasks``; None: the student's task)."""
    name = tier if task is None else f"{task}_{tier}"
    return run_dir / DATASET_DIR / f"round_{round_index:02d}_{name}.npz"


def _save_dataset(path: Path, obs: np.ndarray, labels: np.ndarray) -> None:
    buf = io.BytesIO()
    np.savez(buf, observations=obs, actions=labels)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())


def _load_dataset(path: Path, obs_dim: int, history: int = 1) -> tuple[np.ndarray, np.ndarray] | None:
    """A cached dataset, or None where there is none or it is unreadable (it is collected again). ``obs_dim``: one
    observation's size; with ``history`` K > 1 the rows hold K of them, NaN in the slots before an episode's
    start (:func:`~softpvtol_gym.baselines.training.teachers.collect`)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            obs, labels = data["observations"], data["actions"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # a truncated or crafted file
        _say(f"distill: {path} is unreadable ({exc}); collecting it again")
        return None
    if obs.ndim != 2 or obs.shape[1] != obs_dim * history or labels.shape != (obs.shape[0], 4) or \
            not (np.isfinite(obs[:, -obs_dim:]).all() and not np.isinf(obs).any() and np.isfinite(labels).all()):
        _say(f"distill: {path} does not hold ({history} x {obs_dim}-entry observations, 4 actions); collecting it "
             f"again")
        return None
    return obs, labels


# --------------------------------------------------------------------------------------------- fit
def sample_weights(observations: np.ndarray, precision_scale: float | None) -> np.ndarray | None:
    """The weights (n,) of :class:`DistillConfig`'s ``precision_scale`` (None: none): 1 / (s + |(e_x, e_z)|),
    the errors of observation entries 0 and 1, normalised to a mean of 1."""
    if precision_scale is None:
        return None
    w = 1.0 / (precision_scale + np.hypot(observations[:, 0], observations[:, 1]).astype(np.float64))
    return w / w.mean()


def action_channel_weights(actions: np.ndarray) -> np.ndarray:
    """The weights (4,) of :class:`DistillConfig`'s ``balance_actions``: 1 / the variance of each action channel
    over ``actions`` (n, 4) (a channel that never varies: 1 / 1e-12), normalised to a mean of 1."""
    w = 1.0 / np.maximum(np.asarray(actions, dtype=np.float64).var(axis=0), 1e-12)
    return w / w.mean()


def stacked_inputs(vecnorm, observations: np.ndarray, history: int) -> np.ndarray:
    """The model's inputs (n, K d) for dataset rows ``observations`` (n, K d) of ``history`` K: each observation
    normalised by ``vecnorm``, the slots before an episode's start (NaN) zeros, as VecFrameStack over VecNormalize
    feeds the model."""
    n, width = observations.shape
    one = vecnorm.normalize_obs(observations.reshape(n * history, width // history)).reshape(n, width)
    return np.where(np.isnan(observations), 0.0, one).astype(np.float32)


def fit(model, vecnorm, observations: np.ndarray, actions: np.ndarray, epochs: int, batch_size: int,
        learning_rate: float, seed: int, weights: np.ndarray | None = None,
        channel_weights: np.ndarray | None = None, history: int = 1) -> list[float]:
    """Fit the actor of ``model`` (an SB3 PPO model) to ``actions`` (n, 4) at ``observations`` (n, K d), K =
    ``history`` observations of d entries per row (:func:`stacked_inputs`): VecNormalize's statistics set to
    those of the rows' newest observations, then Adam on the mean squared error of the Gaussian's mean (each
    sample's weighted by ``weights`` (n,), each action channel's by ``channel_weights`` (4,); default 1).
    Returns the mean loss of each epoch."""
    import torch

    newest = observations[:, -(observations.shape[1] // history):]
    rms = vecnorm.obs_rms
    rms.mean = newest.mean(axis=0).astype(np.float64)
    rms.var = newest.var(axis=0).astype(np.float64)
    rms.count = float(len(observations))
    x_all = torch.as_tensor(stacked_inputs(vecnorm, observations, history))
    y_all = torch.as_tensor(actions.astype(np.float32))
    w_all = None if weights is None else torch.as_tensor(weights.astype(np.float32))
    c_all = None if channel_weights is None else torch.as_tensor(np.asarray(channel_weights, dtype=np.float32))
    policy = model.policy
    policy.set_training_mode(True)
    optimizer = torch.optim.Adam(actor_parameters(policy), lr=learning_rate)
    n = len(x_all)
    steps_per_epoch = max(1, -(-n // batch_size))
    total = epochs * steps_per_epoch
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: max(0.0, 1.0 - k / total))
    generator = torch.Generator().manual_seed(int(seed))
    losses = []
    for _ in range(epochs):
        order = torch.randperm(n, generator=generator)
        running = 0.0
        for b in range(steps_per_epoch):
            idx = order[b * batch_size:(b + 1) * batch_size]
            loss = action_gap(policy, x_all[idx], y_all[idx], None if w_all is None else w_all[idx], c_all)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
            running += float(loss.detach()) * len(idx)
        losses.append(running / n)
    policy.set_training_mode(False)
    return losses


def _fresh_student(config: DistillConfig, run_dir: Path, dataset_size: int):
    """(run config, vecnorm, model) of a student with its initial weights (the same for every round's fit)."""
    run_config = config.run_config(dataset_size)
    _, vecnorm, model = prepare(run_config, run_dir)
    vecnorm.training = False
    return run_config, vecnorm, model


# --------------------------------------------------------------------------------------------- run
def distill(config: DistillConfig, run_dir: Path, resume: bool = False, progress_bar: bool = False,
            teacher=None) -> dict:
    """Distil ``config.teacher`` (or the policy ``teacher``: any object with ``predict`` on the student's
    observations, 21 entries) into a student saved in ``run_dir`` as a finished run. Returns
    ``{"policy": LearnedPolicy, "run_config", "record"}`` (``record``: what ``distill.json`` holds).

    ``resume=False`` refuses a ``run_dir`` that holds a distilled run or datasets; ``resume=True`` loads the
    datasets already collected (they must be of the same config) and continues."""
    import torch

    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError(f"run directory {run_dir} is a file; choose a directory for --out")
    torch.set_num_threads(torch_threads())
    run_config = config.run_config()  # validated before anything is written
    obs_dim = OBS_DIM + N_ERROR_INTEGRALS  # one observation of the student (config.env_options)
    teacher = teacher if teacher is not None else teacher_policy(config.teacher, config.task, config.env_options)
    run_dir.mkdir(parents=True, exist_ok=True)
    with DirectoryLock(run_dir, "run directory"):
        record_path = run_dir / DISTILL_FILE
        if record_path.exists() or (run_dir / DATASET_DIR).exists():
            if not resume:
                raise ConfigError(f"{run_dir} already holds a distilled run; pass --resume to continue it or choose "
                                  f"another --out (nothing was overwritten)")
            _check_same_config(run_dir, config)
        atomic_write_text(run_dir / "distill_config.json", json.dumps(config.to_dict(), indent=2))
        bar = _progress(progress_bar, config)
        data_obs, data_act, rounds = [], [], []
        student = None
        t0 = time.perf_counter()
        for k in range(config.rounds):
            for i, task in enumerate(config.tasks):
                for j, tier in enumerate(config.tiers):
                    path = _dataset_path(run_dir, k, tier, task if i else None)
                    cached = _load_dataset(path, obs_dim, config.history)
                    if cached is None:
                        cached = _collect_round(teacher, config, task, tier, config.collection_seed(k, j, i), student,
                                                bar, teacher_share=config.round_teacher_share(k) if k else 0.0)
                        _save_dataset(path, *cached)
                    elif bar is not None:
                        bar(len(cached[0]))
                    data_obs.append(cached[0])
                    data_act.append(cached[1])
            obs, act = np.concatenate(data_obs), np.concatenate(data_act)
            run_config, vecnorm, model = _fresh_student(config, run_dir, len(obs))
            losses = fit(model, vecnorm, obs, act, config.epochs, config.batch_size, config.learning_rate,
                         config.seed, weights=sample_weights(obs[:, -obs_dim:], config.precision_scale),
                         channel_weights=action_channel_weights(act) if config.balance_actions else None,
                         history=config.history)
            student = LearnedPolicy(model, vecnorm, inference="lean")
            this_round, this_round_labels = (d[-len(config.tasks) * len(config.tiers):] for d in (data_obs, data_act))
            entry = {"round": k, "kind": "behaviour cloning" if k == 0 else "dagger",
                     "samples": int(sum(len(o) for o in this_round)), "aggregate": int(len(obs)),
                     "loss_first_epoch": losses[0], "loss_last_epoch": losses[-1], "losses": losses,
                     **({} if config.residual_on is None else {"labels_at_clip": _clip_shares(this_round_labels)}),
                     "evaluation": _evaluate_round(student, teacher, config, k)}
            rounds.append(entry)
            _say(f"distill round {k} ({entry['kind']}): {entry['aggregate']:,} samples, loss {losses[0]:.3g} -> "
                 f"{losses[-1]:.3g}" + _eval_line(entry["evaluation"]))
        model.num_timesteps = int(len(obs))
        seconds = time.perf_counter() - t0
        write_model_files(run_dir, model, vecnorm, run_config, "run")
        record = {"config": config.to_dict(), "student": {"algo": "ppo", "action_mode": config.action_mode,
                                                         "env_options": config.student_env_options,
                                                         "net_arch": list(config.net_arch)},
                  "rounds": rounds, "seconds": seconds}
        atomic_write_text(record_path, json.dumps(record, indent=2))
    return {"policy": student, "run_config": run_config, "record": record}


def _collect_round(teacher, config: DistillConfig, task: str, tier: str, seed: int, student, bar,
                   teacher_share: float = 0.0) -> tuple:
    """One round's dataset on one task and tier: ``config.episodes`` episodes from seed ``seed`` on, the last
    ``config.wide_episodes()`` before the last ``config.attitude_episodes()`` started wide, those turned; with a
    student, the teacher acts at a step with probability ``teacher_share``."""
    wide, turned = config.wide_episodes(), config.attitude_episodes()
    parts = []
    first = seed
    for count, start in ((config.episodes - wide - turned, "task"), (wide, "wide"), (turned, "attitude")):
        if count:
            parts.append(collect(teacher, task, tier, count, first, student=student, progress=bar,
                                 env_options={**config.env_options, "start_distribution": start},
                                 teacher_share=teacher_share, history=config.history,
                                 privileged=config.privileged, residual_on=config.residual_on,
                                 residual_scale=config.residual_scale, residual_base=config.residual_base))
        first += count
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _clip_shares(labels: list) -> list[float]:
    """Per action channel, the share of a residual student's labels (arrays (n, 4)) at the residual's clip, +-1."""
    return [float(v) for v in (np.abs(np.concatenate(labels)) >= 1.0).mean(axis=0)]


def _check_same_config(run_dir: Path, config: DistillConfig) -> None:
    path = run_dir / "distill_config.json"
    try:
        saved = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--resume: {path} is unreadable ({exc}); start the run over in another --out") from None
    saved = {**EARLIER_DEFAULTS, **saved} if isinstance(saved, dict) else saved
    if saved != config.to_dict():
        diff = sorted(k for k in set(saved) | set(config.to_dict()) if saved.get(k) != config.to_dict().get(k))
        raise ConfigError(f"--resume: the run in {run_dir} was made with other settings ({', '.join(diff)}); "
                          f"pass the same options or choose another --out")


def evaluation_key(config: DistillConfig, task: str, tier: str) -> str:
    """The key of a task's and tier's evaluation in a round's record: the tier on the student's task, else
    ``"<task> <tier>"``."""
    return tier if task == config.task else f"{task} {tier}"


def _evaluate_round(student, teacher, config: DistillConfig, round_index: int) -> dict:
    """Per task and tier (:func:`evaluation_key`): the student's and the teacher's summaries on the same
    evaluation episodes."""
    if config.eval_episodes == 0:
        return {}
    seed = DISTILL_EVAL_SEED + 1_000 * config.seed
    out = {}
    for task in config.tasks:
        for tier in config.tiers:
            row = {}
            for who, policy, mode, options in (("student", student, config.action_mode, config.student_env_options),
                                               ("teacher", teacher, "actuators", config.env_options)):
                if who == "teacher" and round_index > 0:
                    continue  # the same episodes as round 0's
                eps = run_episodes(policy, mode, task, tier, config.eval_episodes, seed, env_kwargs=options)
                row[who] = summarize(eps)
            out[evaluation_key(config, task, tier)] = row
    return out


def _eval_line(evaluation: dict) -> str:
    parts = []
    for tier, row in evaluation.items():
        s = row["student"]
        steady = s.get("mean_rms_position_error_steady")
        parts.append(f"{tier}: student last half {'crashed' if steady is None else f'{steady:.4f} m'}, "
                     f"crash rate {s['crash_rate']:.2f}")
    return ("; " + "; ".join(parts)) if parts else ""


def _progress(enabled: bool, config: DistillConfig):
    """A callable counting collected samples on a tqdm bar (None when disabled or tqdm is missing)."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    steps = max(int(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=t).sim.max_steps)
                for t in config.tasks)  # at most
    bar = tqdm(total=config.collections * config.episodes * steps, unit="sample",
               desc="distill", file=sys.stderr)
    return bar.update


def distill_table(record: dict) -> str:
    """A Markdown table of a distilled run's record (``distill.json``): per round and tier, the student's mean
    position errors per window and crashes on the evaluation episodes, below them the teacher's on the same."""
    windows = ("rms_position_error_transient", "rms_position_error_steady", "max_position_error_final_5s")

    def cells(s: dict) -> str:
        vals = [s.get(f"mean_{w}") for w in windows]
        text = ["crashed" if v is None else f"{v:.2e}" for v in vals]
        return " | ".join(text) + f" | {round(s['crash_rate'] * s['episodes'])}/{s['episodes']}"

    lines = ["| round | samples (all rounds) | tier | policy | first quarter [m] | last half [m] | max last 5 s [m] "
             "| crashes |", "|---|---|---|---|---|---|---|---|"]
    teachers = {}
    for r in record["rounds"]:
        for tier, row in r["evaluation"].items():
            teachers.setdefault(tier, row.get("teacher"))
            lines.append(f"| {r['round']} ({r['kind']}) | {r['aggregate']:,} | {tier} | student | "
                         f"{cells(row['student'])} |")
    for tier, s in teachers.items():
        if s is not None:
            lines.append(f"| | | {tier} | teacher ({record['config']['teacher']}) | {cells(s)} |")
    return "\n".join(lines)
