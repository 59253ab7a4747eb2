"""One evaluator for every policy with a stable-baselines3 ``predict`` (learned or analytic).

Episodes are fixed and seeded: evaluation episode i of a call with ``seed`` is sub-env i of the
native vector env reset with ``seed`` (so it gets seed + i), the same for every policy. Training seeds
live below :data:`EVAL_SEED_OFFSET`; evaluation seeds start at it, so the two never overlap.

Per-episode metrics (all computed on the true, noise-free state until the episode ends):

* ``return``: sum of rewards;
* ``rms_position_error`` [m]: RMS over steps of |(x, z) - (x_ref, z_ref)|;
* ``rms_attitude_error`` [rad]: RMS over steps of the wrapped theta - theta_ref;
* ``control_effort``: mean over steps of mean(a_n^2), the env's effort measure (see the env's
  Rewards section: applied actuators normalised by their limits, relative to hover thrust), clipped at 1;
* ``crashed``: the episode terminated (any termination reason) before its time limit;
* ``length``: number of control steps.
"""

from __future__ import annotations

import numpy as np

from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

EVAL_SEED_OFFSET = 1_000_000
EPISODE_METRICS = ("return", "rms_position_error", "rms_attitude_error", "control_effort", "crashed", "length")
_EFFORT_WEIGHT = 0.1  # the env's effort reward term is -0.1 * min(mean(a_n^2), 1)


def run_episodes(policy, action_mode: str, task: str, tier: str, episodes: int, seed: int,
                 env_kwargs: dict | None = None) -> list[dict]:
    """Run ``policy.predict`` (deterministic) on ``episodes`` seeded episodes in parallel; one dict of
    :data:`EPISODE_METRICS` per episode."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env = SoftPVTOLVectorEnv(num_envs=episodes, action_mode=action_mode, task=task, tier=tier, **(env_kwargs or {}))
    sim = env.sim
    obs, _ = env.reset(seed=seed)
    n = episodes
    ret, sq_pos, sq_att, effort, length = (np.zeros(n) for _ in range(5))
    done, crashed, start = np.zeros(n, bool), np.zeros(n, bool), np.ones(n, bool)
    while not done.all():
        action, _ = policy.predict(obs, episode_start=start, deterministic=True)
        start[:] = False
        obs, reward, term, trunc, info = env.step(action)
        live = ~done
        q = sim.q
        e_pos = q[:, :2] - sim.qr[:, :2]
        e_att = np.arctan2(np.sin(q[:, 2] - sim.qr[:, 2]), np.cos(q[:, 2] - sim.qr[:, 2]))
        ret[live] += reward[live]
        sq_pos[live] += np.sum(e_pos[live] ** 2, axis=1)
        sq_att[live] += e_att[live] ** 2
        effort[live] += -info["reward_terms"]["effort"][live] / _EFFORT_WEIGHT
        length[live] += 1
        crashed |= term & live
        done |= term | trunc
    env.close()
    steps = np.maximum(length, 1)
    return [
        {
            "return": float(ret[i]),
            "rms_position_error": float(np.sqrt(sq_pos[i] / steps[i])),
            "rms_attitude_error": float(np.sqrt(sq_att[i] / steps[i])),
            "control_effort": float(effort[i] / steps[i]),
            "crashed": bool(crashed[i]),
            "length": int(length[i]),
        }
        for i in range(n)
    ]


def summarize(episodes: list[dict]) -> dict:
    """Means over episodes of :data:`EPISODE_METRICS` (``crash_rate`` for ``crashed``)."""
    out = {"episodes": len(episodes)}
    for key in EPISODE_METRICS:
        vals = np.array([e[key] for e in episodes], dtype=float)
        out["crash_rate" if key == "crashed" else f"mean_{key}"] = float(vals.mean())
    return out


def evaluate(policy, action_mode: str, task: str, tier: str, episodes: int, seed: int,
             env_kwargs: dict | None = None) -> dict:
    """``{"episodes": [...], "summary": {...}}`` of :func:`run_episodes` and :func:`summarize`."""
    eps = run_episodes(policy, action_mode, task, tier, episodes, seed, env_kwargs)
    return {"episodes": eps, "summary": summarize(eps)}
