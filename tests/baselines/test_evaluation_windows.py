"""The evaluator's windowed metrics (first quarter, last half, max over the last 5 s), the crashed-window
rule and the compute per step, checked against a hand computation on a recorded trajectory."""

from __future__ import annotations

import time

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.evaluation import (
    EPISODE_METRICS,
    WINDOW_METRICS,
    identical_episodes,
    run_episodes,
    summarize,
    window_scores,
    window_steps,
    without_timing,
)
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv


class FallsAfter:
    """The passivity controller; from control step ``switch`` on, the envs in ``falling`` get the lowest
    actuator command (-1: no thrust), so they fall to the ground: a crash at a known place."""

    def __init__(self, env, switch: int, falling: list[int]):
        self.inner, self.switch, self.falling, self.steps = PassivityPolicy.from_env(env), switch, falling, 0

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, _ = self.inner.predict(obs, episode_start=episode_start)
        if self.steps >= self.switch:
            action = np.array(action, copy=True)
            action[self.falling] = -1.0
        self.steps += 1
        return action, None


def _recorded_errors(policy, n: int, seed: int, **env_kwargs) -> tuple[list[np.ndarray], np.ndarray]:
    """A readable reference: step the env with ``policy``, record each live episode's position error after
    every step; (errors per episode, crashed)."""
    env = SoftPVTOLVectorEnv(num_envs=n, action_mode="actuators", **env_kwargs)
    obs, _ = env.reset(seed=seed)
    errors: list[list[float]] = [[] for _ in range(n)]
    done, crashed, start = np.zeros(n, bool), np.zeros(n, bool), np.ones(n, bool)
    while not done.all():
        action, _ = policy.predict(obs, episode_start=start)
        start[:] = False
        obs, _, term, trunc, _ = env.step(action)
        e = np.hypot(env.sim.q[:, 0] - env.sim.qr[:, 0], env.sim.q[:, 1] - env.sim.qr[:, 1])
        for i in np.flatnonzero(~done):
            errors[i].append(e[i])
        crashed |= term & ~done
        done |= term | trunc
    env.close()
    return [np.asarray(x) for x in errors], crashed


def test_window_steps_are_the_quarter_the_half_and_the_last_five_seconds_of_each_task():
    for task, steps in (("hover", 1000), ("track_random", 2000), ("track_paper", 4000)):
        env = SoftPVTOLVectorEnv(num_envs=1, task=task)
        assert (env.sim.max_steps, env.sim.dt) == (steps, 0.01)
        assert window_steps(steps, 0.01) == {"transient": (0, steps // 4), "steady": (steps // 2, steps),
                                             "final_5s": (steps - 500, steps)}
    assert window_steps(300, 0.01)["final_5s"] == (0, 300)  # shorter than 5 s: the whole episode
    assert window_steps(3, 0.02) == {"transient": (0, 1), "steady": (2, 3), "final_5s": (0, 3)}
    with pytest.raises(ValueError, match="max_steps must be >= 1"):
        window_steps(0, 0.01)


def test_window_metrics_match_a_hand_computation_and_a_crashed_episode_has_crashed_windows():
    kw = dict(task="hover", tier="wind", max_episode_seconds=8.0)  # L = 800 steps: windows 0-200, 400-800, 300-800
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover")
    switch = 250  # after the first quarter: episode 1 falls from here on
    got = run_episodes(FallsAfter(probe, switch, [1]), "actuators", "hover", "wind", 2, 1_000_000,
                       env_kwargs={"max_episode_seconds": 8.0})
    errors, crashed = _recorded_errors(FallsAfter(probe, switch, [1]), 2, 1_000_000, **kw)
    assert list(crashed) == [False, True] and len(errors[0]) == 800 and switch < len(errors[1]) < 800
    for ep, e, c in zip(got, errors, crashed):
        assert set(ep) == set(EPISODE_METRICS) and ep["crashed"] == c and ep["length"] == len(e)
        assert ep["rms_position_error"] == pytest.approx(np.sqrt(np.mean(e ** 2)), rel=1e-12)
        assert ep["rms_position_error_transient"] == pytest.approx(np.sqrt(np.mean(e[:200] ** 2)), rel=1e-12)
    full = errors[0]
    assert got[0]["rms_position_error_steady"] == pytest.approx(np.sqrt(np.mean(full[400:] ** 2)), rel=1e-12)
    assert got[0]["max_position_error_final_5s"] == pytest.approx(full[300:].max(), rel=1e-12)
    # the crash came after the first quarter (kept) and before the end: the last half and the final 5 s crashed
    assert got[1]["rms_position_error_transient"] is not None
    assert got[1]["rms_position_error_steady"] is None and got[1]["max_position_error_final_5s"] is None
    s = summarize(got)
    assert s["crash_rate"] == 0.5 and s["mean_rms_position_error_steady"] is None
    assert s["crashed_rms_position_error_steady"] == 1 and s["crashed_rms_position_error_transient"] == 0
    assert s["mean_rms_position_error_transient"] == pytest.approx(
        np.mean([g["rms_position_error_transient"] for g in got]))
    assert list(window_scores(got, "rms_position_error_steady")) == [got[0]["rms_position_error_steady"], np.inf]


class Recording(FallsAfter):
    """FallsAfter that keeps a copy of every observation batch it is given."""

    def __init__(self, *args):
        super().__init__(*args)
        self.seen = []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        self.seen.append(np.array(obs, copy=True))
        return super().predict(obs, episode_start=episode_start)


def test_a_finished_episode_s_entry_gets_its_last_running_observation_not_the_terminal_one():
    # the policy acts on the whole batch until every episode ends; a finished entry's terminal observation
    # (a diverged one may be outside what an analytic controller accepts) is replaced by its last observation
    # of the running episode, and that entry is never scored again
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover")
    policy = Recording(probe, 250, [1])
    got = run_episodes(policy, "actuators", "hover", "nominal", 2, 1_000_000)
    end = got[1]["length"]  # the call that got the terminal observation without the replacement
    assert got[1]["crashed"] and end < got[0]["length"] == len(policy.seen)
    last = policy.seen[end - 1][1]
    assert all(np.array_equal(seen[1], last) for seen in policy.seen[end:])
    assert not np.array_equal(policy.seen[end][0], policy.seen[end - 1][0])  # the running entry moves on


class Sleepy:
    """Sleeps 2 ms per predict call (for the whole batch): the evaluator's compute per step is its per-env share."""

    def __init__(self, env):
        self.inner = PassivityPolicy.from_env(env)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        time.sleep(0.002)
        return self.inner.predict(obs, episode_start=episode_start)


def test_compute_per_step_is_the_predict_time_per_env_and_only_measured_when_asked():
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover")
    kw = {"max_episode_seconds": 0.5}
    timed = run_episodes(Sleepy(probe), "actuators", "hover", "nominal", 2, 1_000_000, env_kwargs=kw, timing=True)
    plain = run_episodes(Sleepy(probe), "actuators", "hover", "nominal", 2, 1_000_000, env_kwargs=kw)
    for t in timed:
        assert 1000 <= t["compute_us_per_step"] < 50_000  # 2 ms per call, shared by 2 envs: >= 1 ms each
        assert t["compute_us_per_step"] <= t["compute_us_per_step_p99"] <= t["compute_us_per_step_max"]
    assert not any(k.startswith("compute") for k in plain[0]) and [without_timing(t) for t in timed] == plain
    assert summarize(timed)["median_compute_us_per_step"] >= 1000 and "median_compute_us_per_step" not in \
        summarize(plain)


def test_identical_episodes_ignore_the_wall_time_and_nothing_else():
    ep = {k: 1.0 for k in EPISODE_METRICS} | {"crashed": False, "length": 10, "compute_us_per_step": 3.0}
    assert identical_episodes([ep, dict(ep, compute_us_per_step=9.0)])
    for key in EPISODE_METRICS:
        assert not identical_episodes([ep, dict(ep, **{key: 2})]), key
    assert not identical_episodes([ep, dict(ep, rms_position_error_steady=None)])
    assert set(WINDOW_METRICS) <= set(EPISODE_METRICS)
