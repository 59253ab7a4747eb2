"""A job's episodes: its policy, fresh for each run (:func:`job_policy`), its test and selection episodes, the
replay that adds a newly recorded metric to recorded episodes (:func:`with_new_metrics`), and the round-off probe
of a deterministic task and tier (:func:`roundoff_episodes`). ``job`` is always a
:class:`~softpvtol_gym.baselines.leaderboard.jobs.Job` (not imported here: ``jobs`` imports this module)."""

from __future__ import annotations

from pathlib import Path

import softpvtol_gym
from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EPISODE_METRICS, run_episodes
from softpvtol_gym.baselines.leaderboard.spec import ANALYTIC_KINDS
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

#: the round-off probe of a deterministic episode: its start (x, then z) moved by -/+ this much [m], one episode
#: each: far below any sensor noise or parameter error of a tier, far above float64's spacing at 1 m (2e-16), so it
#: shows how much the closed loop amplifies the last bits (a knife edge), not a different task
ROUNDOFF_SHIFT_M = 1e-9


def job_episodes(job, out: Path, task: str, tier: str, which: str) -> list[dict]:
    """The ``which`` ("test" or "selection") episodes of ``job`` on a task and tier, with a policy of their own."""
    policy, env_kwargs = job_policy(job, out)
    count, seed = ((job.eval_episodes, job.eval_seed) if which == "test" else
                   (job.selection_episodes, job.selection_seed))
    return run_episodes(policy, job.action_mode, task, tier, count, seed, env_kwargs=env_kwargs, timing=True)


#: metrics a replay may reproduce to the last bits only: the attitude error goes through numpy's vectorised
#: sin, cos and arctan2, whose last bit can differ between numpy builds and array layouts; the trajectory (every
#: other metric) must still be the same to the bit
_LAST_BIT_METRICS = ("rms_attitude_error",)


def with_new_metrics(job, out: Path, task: str, tier: str, recorded: list[dict], which: str) -> list[dict]:
    """``recorded`` episodes with the metrics of :data:`EPISODE_METRICS` they lack, from a re-run without timing
    whose every recorded metric must equal the recorded one exactly (a replay; :data:`_LAST_BIT_METRICS` to a
    relative 1e-12); ConfigError otherwise. The recorded values are kept."""
    if all(k in e for e in recorded for k in EPISODE_METRICS):
        return recorded
    policy, env_kwargs = job_policy(job, out)
    count, seed = ((job.eval_episodes, job.eval_seed) if which == "test" else
                   (job.selection_episodes, job.selection_seed))
    again = run_episodes(policy, job.action_mode, task, tier, count, seed, env_kwargs=env_kwargs)
    merged = []
    for i, (old, new) in enumerate(zip(recorded, again)):
        differ = [k for k in EPISODE_METRICS if k in old and old[k] != new[k] and not (
            k in _LAST_BIT_METRICS and abs(old[k] - new[k]) <= 1e-12 * abs(old[k]))]
        if differ:
            k = differ[0]
            raise ConfigError(f"job {job.name}: {which} episode {i} on {task}/{tier} no longer reproduces ({k} "
                              f"{old[k]!r} recorded, {new[k]!r} now); re-evaluate it: python baselines/run_jobs.py "
                              f"--reevaluate --only {job.name.split('/')[0]}")
        merged.append({**old, **{k: new[k] for k in EPISODE_METRICS if k not in old}})
    return merged


#: the round-off probe's starts: (state index, sign) of the shift (x -, x +, z -, z +)
ROUNDOFF_STARTS = ((0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0))


def roundoff_episodes(job, out: Path, task: str, tier: str) -> list[dict]:
    """The round-off probe of a deterministic (task, tier): test episode 0 again, once per start of
    :data:`ROUNDOFF_STARTS` (its initial configuration q0 with x or z moved by -/+ :data:`ROUNDOFF_SHIFT_M`), each
    with a fresh policy; one dict of :data:`EPISODE_METRICS` per start."""
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode=job.action_mode, task=task, tier=tier,
                               **job_policy(job, out)[1])
    probe.reset(seed=job.eval_seed)
    q0 = probe.sim.q[0].copy()
    probe.close()
    episodes = []
    for index, sign in ROUNDOFF_STARTS:
        start = q0.copy()
        start[index] += sign * ROUNDOFF_SHIFT_M
        policy, env_kwargs = job_policy(job, out)
        episodes += run_episodes(policy, job.action_mode, task, tier, 1, job.eval_seed, env_kwargs=env_kwargs,
                                 reset_options={"q0": start})
    return episodes


def job_policy(job, out: Path) -> tuple:
    """(a fresh policy, env_kwargs) of a job: a learned job's model from its folder ``out`` with the job's
    ``inference``, on the base loop it was trained on; an analytic job's controller (:func:`analytic_policy`)."""
    if job.learned:
        policy, run_config = LearnedPolicy.load(out, inference=job.inference)
        return policy, run_config.eval_env_kwargs()
    return analytic_policy(job)


def analytic_policy(job) -> tuple:
    """(policy, env_kwargs) of an analytic job: a PassivityPolicy with the job's allocation and loop, or
    ``softpvtol_gym.MPCPolicy.from_env(env, **options)`` (imported here: the MPC needs the ``mpc`` extra)."""
    if job.kind == "passivity":
        env_kwargs = {"allocation": job.allocation, "controller_loop": job.loop or job.allocation}
        probe = SoftPVTOLVectorEnv(num_envs=1, action_mode=job.action_mode, task=job.task, **env_kwargs)
        return PassivityPolicy.from_env(probe), env_kwargs
    if job.kind == "mpc":
        probe = SoftPVTOLVectorEnv(num_envs=1, action_mode=job.action_mode, task=job.task)
        options = {k: list(v) if isinstance(v, tuple) else v for k, v in job.options}
        try:
            return softpvtol_gym.MPCPolicy.from_env(probe, **options), {}
        except ImportError as exc:  # the mpc extra (CasADi) is missing: the message names it
            raise ConfigError(f"job {job.name}: {exc}; or remove the mpc entry from the spec") from None
    raise ConfigError(f"job {job.name}: unknown analytic kind {job.kind!r}; expected one of {list(ANALYTIC_KINDS)}")
