"""One evaluator for every policy with a stable-baselines3 ``predict`` (learned or analytic)."""

from __future__ import annotations

import numpy as np

from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


def evaluate(policy, action_mode: str, task: str, tier: str, episodes: int, seed: int) -> dict:
    """Run ``policy.predict`` (learned or analytic) on ``episodes`` episodes, sub-env i seeded seed + i.

    Returns the mean return, the mean over episodes of the RMS position error [m] until the episode
    ends, and the crash rate (episodes that terminated before the time limit)."""
    env = SoftPVTOLVectorEnv(num_envs=episodes, action_mode=action_mode, task=task, tier=tier)
    obs, _ = env.reset(seed=seed)
    ret, sq, cnt = np.zeros(episodes), np.zeros(episodes), np.zeros(episodes)
    done, crashed, start = np.zeros(episodes, bool), np.zeros(episodes, bool), np.ones(episodes, bool)
    while not done.all():
        action, _ = policy.predict(obs, episode_start=start, deterministic=True)
        start[:] = False
        obs, reward, term, trunc, _ = env.step(action)
        live = ~done
        ret[live] += reward[live]
        q, _ = env.state
        sq[live] += np.sum((q[live, :2] - env._sim.qr[live, :2]) ** 2, axis=1)
        cnt[live] += 1
        crashed |= term & live
        done |= term | trunc
    return {
        "mean_return": float(ret.mean()),
        "rms_position_error_m": float(np.sqrt(sq / np.maximum(cnt, 1)).mean()),
        "crash_rate": float(crashed.mean()),
        "episodes": episodes,
    }
