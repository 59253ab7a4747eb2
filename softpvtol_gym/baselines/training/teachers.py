"""Teachers: the controllers a learned policy imitates (distillation, the imitation term of fine-tuning), and
the collection of their labelled episodes."""

from __future__ import annotations

import numpy as np

import softpvtol_gym
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

__all__ = ["TEACHERS", "STUDENT_ENV_OPTIONS", "RESIDUAL_STUDENT_SCALE", "student_env_options", "teacher_policy",
           "collect"]

#: the teachers by name: the passivity loops acting on the actuators, and the MPC (the ``mpc`` extra)
TEACHERS = ("paper", "exact", "improved", "bounded", "integral", "extended", "mpc")
#: the student's env options: the error integrals observed (3 more entries)
STUDENT_ENV_OPTIONS = {"observe_error_integral": True}
#: a residual student's correction at action +-1 (the env's ``residual_scale`` in the actuator space): T_max on each
#: thrust, 2 tau_max on each arm torque, so that any correction from inside the actuator box to the box is one
RESIDUAL_STUDENT_SCALE = 2.0


def student_env_options(teacher: str, teacher_integral: bool = False) -> dict:
    """The env options of a student of ``teacher``: the error integrals observed, and with ``teacher_integral``
    for a teacher with integral action (the integral loop), integrated as the teacher integrates them (each
    error clipped to its ``integral_error_limits`` first, the integral to its ``integral_limits``), so that far
    from the reference (track_paper's start) the student still observes its teacher's state."""
    options = dict(STUDENT_ENV_OPTIONS)
    loop = LOOPS.get(teacher, {})
    if teacher_integral and "integral_limits" in loop:
        options.update(error_integral_limit=float(loop["integral_limits"][0]),
                       error_integral_error_limit=float(loop["integral_error_limits"][0]))
    return options


def teacher_policy(name: str, task: str, env_options: dict | None = None):
    """A fresh teacher of :data:`TEACHERS` acting on the actuators of an env with ``env_options``
    (a passivity loop with its own allocation, or ``MPCPolicy`` with its defaults)."""
    opts = dict(STUDENT_ENV_OPTIONS if env_options is None else env_options)
    if name == "mpc":
        probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task, **opts)
        return softpvtol_gym.MPCPolicy.from_env(probe)
    if name not in TEACHERS:
        raise ConfigError(f"teacher must be one of {list(TEACHERS)}, got {name!r}")
    allocation = "exact" if name == "extended" else LOOPS[name]["allocation"]
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task, allocation=allocation,
                               controller_loop=name, **opts)
    return softpvtol_gym.PassivityPolicy.from_env(probe)


def collect(teacher, task: str, tier: str, episodes: int, seed: int, student=None,
            env_options: dict | None = None, progress=None,
            teacher_share: float = 0.0, history: int = 1, privileged: bool = False,
            residual_on: str | None = None, residual_scale: float = RESIDUAL_STUDENT_SCALE,
            residual_base: str = "unsaturated") -> tuple[np.ndarray, np.ndarray]:
    """(observations (n, d), teacher actions (n, 4)) of ``episodes`` seeded episodes (seeds seed + i) on the
    actuators mode: flown by the teacher (``student=None``) or by ``student`` with the teacher labelling
    every observation the student visits; with ``teacher_share`` p > 0 the teacher's action is applied instead of
    the student's at each step of each episode with probability p (drawn from a generator seeded with ``seed``).
    A teacher with an ``observe_applied`` method (the MPC) is told the actions applied. Each episode's steps until
    it ends (time limit or crash).

    ``history`` K > 1: each row holds the episode's last K observations, oldest first (n, K d), as SB3's
    VecFrameStack stacks them, with NaN in the slots before the episode's start (VecFrameStack's zeros are zeros
    of the normalised observation: the fit puts them there after normalising).

    ``privileged``: the teacher acts on the noise-free observations of the true state
    (:meth:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv.noise_free_observations`), the rows hold the observations
    (noisy where the tier has sensor noise) that the student sees; where the tier lags the actuators, a teacher
    with ``observe_applied`` is told after each step the inputs the plant received, the actuators' true lagged state
    (:meth:`~softpvtol_gym.envs.vector.SoftPVTOLVectorEnv.applied_actions`), instead of the actions commanded.

    ``residual_on`` (a passivity loop): the episodes fly the residual mode on that loop (``residual_space=
    "actuators"``, ``residual_scale``), the student commands corrections, and the labels are the corrections that
    turn the loop's action into the teacher's, clip((teacher - loop) / residual_scale, -1, 1), with the loop's
    action computed beside the env on the observations the env's loop acts on (:func:`teacher_policy` of the loop:
    its command before the actuator box's clip, to which the env adds the correction; with ``residual_base=
    "saturated"`` that command clipped to the box, as the env's option of that name adds it). A teacher with memory
    of its inputs is told the actuators the plant got."""
    options = dict(STUDENT_ENV_OPTIONS if env_options is None else env_options)
    loop = None if residual_on is None else teacher_policy(residual_on, task, options)
    if loop is not None:
        options.update(controller_loop=residual_on, residual_space="actuators", residual_scale=residual_scale,
                       residual_base=residual_base)
    env = SoftPVTOLVectorEnv(num_envs=episodes, action_mode="actuators" if loop is None else "residual", task=task,
                             tier=tier, **options)
    obs, _ = env.reset(seed=seed)
    done, start = np.zeros(episodes, bool), np.ones(episodes, bool)
    draws = np.random.default_rng(seed) if student is not None and teacher_share > 0 else None
    observations, labels = [], []
    stack = np.full((episodes, history, obs.shape[1]), np.nan, dtype=np.float32)  # each episode's last observations
    seen = env.noise_free_observations() if privileged else obs  # what the teacher acts on
    remembers = hasattr(teacher, "observe_applied")  # a teacher with memory of its inputs
    lagged = privileged and remembers and env.config.tier_values["actuator_time_constant"] > 0
    while not done.all():
        label, _ = teacher.predict(seen, episode_start=start, deterministic=True)
        if loop is not None:  # the correction from the loop's action to the teacher's
            loop.predict(obs, episode_start=start, deterministic=True)
            base = loop.unclipped_actions()  # the env adds the correction to the loop's command as computed
            if residual_base == "saturated":  # or to that command clipped to the actuator box
                base = np.clip(base, -1.0, 1.0)
            label = np.clip((label.astype(np.float64) - base) / residual_scale, -1.0, 1.0).astype(np.float32)
        action = label if student is None else student.predict(obs, episode_start=start, deterministic=True)[0]
        if draws is not None:
            action = np.where((draws.random(episodes) < teacher_share)[:, None], label, action)
        if student is not None and remembers and not lagged and loop is None:
            teacher.observe_applied(action)
        live = ~done
        stack = np.roll(stack, -1, axis=1)
        stack[start] = np.nan
        stack[:, -1] = obs
        observations.append(stack[live].reshape(int(live.sum()), -1))
        labels.append(np.array(label[live], dtype=np.float32))
        start[:] = False
        previous, previous_seen = obs, seen
        obs, _, term, trunc, _ = env.step(action)
        seen = env.noise_free_observations() if privileged else obs
        if remembers and (lagged or loop is not None):  # the plant's inputs (after the lag where privileged)
            applied = env.applied_actions() if lagged else np.clip(base + residual_scale * action, -1.0, 1.0)
            teacher.observe_applied(np.where(np.isnan(applied), action, applied))
        done |= term | trunc
        if progress is not None:
            progress(int(live.sum()))
        if done.any() and not done.all():  # the policies act on the whole batch: a running row's last observation
            obs = np.where(done[:, None], previous, obs)
            seen = np.where(done[:, None], previous_seen, seen)
    env.close()
    return np.concatenate(observations), np.concatenate(labels)
