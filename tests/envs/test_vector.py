"""Native vector env: bit-for-bit equality with single envs, autoreset, random-action robustness, SB3 adapter."""

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.envs.reward import CRASH_PENALTY
from softpvtol_gym.envs.termination import REASONS
from softpvtol_gym.envs.tiers import BUILTIN_TIERS


@pytest.mark.parametrize(
    "mode, tier",
    [("actuators", "hard"), ("virtual", "noisy"), ("residual", "wind"), ("actuators", "mismatch")],
)
def test_subenv_matches_single_env_bit_for_bit(mode, tier):
    """Same actions: sub-env i == single env reset with seed s + i, across terminations/autoresets."""
    n, s, steps = 3, 11, 120
    kw = dict(action_mode=mode, tier=tier, task="track_random", max_episode_seconds=0.4)
    venv = SoftPVTOLVectorEnv(num_envs=n, **kw)
    singles = [SoftPVTOLEnv(**kw) for _ in range(n)]
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.5, 1.5, (steps, n, venv.single_action_space.shape[0]))
    vo, _ = venv.reset(seed=s)
    so = [e.reset(seed=s + i)[0] for i, e in enumerate(singles)]
    np.testing.assert_array_equal(vo, np.stack(so))
    need_reset = [False] * n
    n_done = 0
    for k in range(steps):
        vo, vr, vterm, vtrunc, _ = venv.step(actions[k])
        for i, e in enumerate(singles):
            if need_reset[i]:  # NEXT_STEP autoreset: this step only resets
                o, _ = e.reset()
                r, term, trunc = 0.0, False, False
                need_reset[i] = False
            else:
                o, r, term, trunc, _ = e.step(actions[k, i])
                need_reset[i] = term or trunc
                n_done += term or trunc
            np.testing.assert_array_equal(vo[i], o)
            assert vr[i] == r and vterm[i] == term and vtrunc[i] == trunc
    assert n_done >= n  # at least one episode end (and autoreset) per sub-env


def test_terminated_episode_reports_reason():
    v = SoftPVTOLVectorEnv(num_envs=16, action_mode="actuators", tier="nominal")
    v.reset(seed=0)
    seen = set()
    for _ in range(400):
        a = np.tile([[1.0, -1.0, 1.0, -1.0]], (16, 1))
        _, _, term, trunc, info = v.step(a)
        for i in np.flatnonzero(term):
            seen.add(info["termination_reason"][i])
    assert seen and seen <= set(REASONS[1:])


MODES_TIERS = [(m, t) for m in ("actuators", "virtual", "residual") for t in BUILTIN_TIERS]


@pytest.mark.parametrize("mode, tier", MODES_TIERS)
def test_random_actions_never_nan(mode, tier):
    """15 configurations x 64 envs x ~105 steps ~ 100,000 random-action steps in total."""
    n, steps = 64, 105
    task = ("hover", "setpoint", "track_paper", "track_random")[
        MODES_TIERS.index((mode, tier)) % 4]
    v = SoftPVTOLVectorEnv(num_envs=n, action_mode=mode, tier=tier, task=task, max_episode_seconds=0.8)
    obs, _ = v.reset(seed=1)
    rng = np.random.default_rng(2)
    ends = 0
    for _ in range(steps):
        a = rng.uniform(-1, 1, (n, v.single_action_space.shape[0]))
        obs, r, term, trunc, info = v.step(a)
        assert np.isfinite(obs).all() and np.isfinite(r).all()
        assert np.isfinite(info["total_energy"]).all()
        for i in np.flatnonzero(term):
            assert info["termination_reason"][i] in REASONS[1:]
        for i in np.flatnonzero(trunc):
            assert info["termination_reason"][i] == "time_limit"
        ends += int((term | trunc).sum())
    assert ends > 0


def test_non_finite_state_terminates_with_finite_observation():
    e = SoftPVTOLEnv(action_mode="virtual", allocation="ideal", params=None)
    # (a curvature beyond pi is refused by reset: the divergence comes from the rate)
    e.reset(seed=0, options={"q0": [0, 2, 0, 0, 0], "qdot0": [0, 0, 0, 1e200, 0]})
    obs, r, term, trunc, info = e.step(np.zeros(5))
    assert term and info["termination_reason"] == "non_finite"
    assert np.isfinite(obs).all() and np.isfinite(r)


@pytest.mark.parametrize("q0, reason", [
    ([0, 2, 0, 3.1, 0], "curvature_limit"), ([0, -0.99, 0, 0, 0], "ground"), ([19.99, 2, 0, 0, 0], "out_of_bounds")])
def test_termination_reasons(q0, reason):
    e = SoftPVTOLEnv(action_mode="virtual", allocation="ideal")
    qd = {"curvature_limit": [0, 0, 0, 20, 0], "ground": [0, -5, 0, 0, 0], "out_of_bounds": [5, 0, 0, 0, 0]}[reason]
    e.reset(seed=0, options={"q0": q0, "qdot0": qd})
    _, r, term, _, info = e.step(np.zeros(5))
    assert term and info["termination_reason"] == reason
    assert info["reward_terms"]["crash"] == -CRASH_PENALTY


def test_vector_seeds_differ_between_subenvs():
    v = SoftPVTOLVectorEnv(num_envs=4)
    o, _ = v.reset(seed=0)
    assert len({tuple(x) for x in o}) == 4


def test_same_step_autoreset_final_obs():
    v = SoftPVTOLVectorEnv(num_envs=2, max_episode_seconds=0.03, autoreset_mode="SameStep")
    v.reset(seed=0)
    for _k in range(3):
        obs, _, _, trunc, info = v.step(np.zeros((2, 4)))
    assert trunc.all() and info["final_obs"][0].shape == (18,)
    assert not np.array_equal(info["final_obs"][0], obs[0])


@pytest.mark.slow  # a short PPO training
def test_sb3_adapter_ppo_and_terminal_observation():
    from stable_baselines3 import PPO

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    venv = SoftPVTOLSB3VecEnv(num_envs=8, task="hover", max_episode_seconds=1.0)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=128, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=2048)
    venv.seed(0)
    venv.reset()
    found = False
    for _ in range(110):
        obs, rew, dones, infos = venv.step(np.zeros((8, 4), np.float32))
        for i in np.flatnonzero(dones):
            assert infos[i]["terminal_observation"].shape == (18,)
            assert "TimeLimit.truncated" in infos[i]
            found = True
    assert found


AIDS = {"residual_gate": 0.05, "precision_reward_weight": 1.0, "action_rate_penalty": 0.1}


@pytest.mark.parametrize("step_infos", [True, False])
@pytest.mark.parametrize("aids", [{}, AIDS])
def test_sb3_adapter_infos_are_the_vector_envs_entries(aids, step_infos):
    """Each of the adapter's info dicts holds sub-env i's entries of the vector env's info (nested dicts too),
    as Python scalars, with SB3's keys where an episode ended; with ``step_infos=False`` only where an episode
    ended (the others are empty)."""
    from gymnasium.vector import AutoresetMode

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    kwargs = dict(num_envs=6, action_mode="residual", task="track_random", max_episode_seconds=0.2, **aids)
    adapter = SoftPVTOLSB3VecEnv(step_infos=step_infos, **kwargs)
    native = SoftPVTOLVectorEnv(autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    adapter.seed(3)
    adapter.reset()
    native.reset(seed=3)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(30):
        a = rng.uniform(-1, 1, (6, 5)).astype(np.float32)
        _, _, dones, infos = adapter.step(a)
        _, _, term, trunc, info = native.step(a)
        keys = [k for k in info if not k.startswith("_") and k not in ("final_obs", "final_info")]
        assert ("residual_gate" in keys) == bool(aids)
        for i in range(6):
            expected = {k: ({kk: vv[i].item() for kk, vv in info[k].items()} if isinstance(info[k], dict)
                            else info[k][i] if info[k].dtype == object else info[k][i].item()) for k in keys}
            if dones[i]:
                ended += 1
                np.testing.assert_array_equal(infos[i].pop("terminal_observation"), info["final_obs"][i])
                assert infos[i].pop("TimeLimit.truncated") == bool(trunc[i] and not term[i])
            assert infos[i] == (expected if step_infos or dones[i] else {})
            assert list(infos[i]) == (keys if step_infos or dones[i] else [])
    assert ended >= 6


def test_diverging_residual_envs_terminate_instead_of_raising():
    """Huge actuator limits and random residuals make sub-envs diverge within a step; the base
    controller then sees a non-finite state (a terminated sub-env is stepped once more before its
    next-step autoreset): the step must not raise, and must return finite values and reasons."""
    env = SoftPVTOLVectorEnv(num_envs=8, action_mode="residual", task="track_paper", actuator_limits=(1e6, 1e6))
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    reasons = set()
    for _ in range(50):
        obs, rew, term, trunc, info = env.step(rng.uniform(-1, 1, (8, 5)).astype(np.float32))
        assert np.isfinite(obs).all() and np.isfinite(rew).all()
        assert all(info["termination_reason"][term])
        reasons |= {r for r in info["termination_reason"][term]}
    assert reasons and reasons <= {"curvature_limit", "ground", "out_of_bounds", "non_finite"}


def test_sb3_adapter_refuses_a_step_infos_that_is_not_a_bool():
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    with pytest.raises(ValueError, match="step_infos must be True or False, got 'no'"):
        SoftPVTOLSB3VecEnv(num_envs=2, step_infos="no")


def _assert_same_outputs(a, b, where):
    """Two step (or reset) results equal bit for bit: arrays, dicts of arrays, object arrays of arrays."""
    if isinstance(a, tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same_outputs(x, y, f"{where}[{i}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _assert_same_outputs(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert a.shape == b.shape, where
        for x, y in zip(a, b):
            _assert_same_outputs(x, y, where)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


@pytest.mark.parametrize("autoreset_mode, kw", [
    ("NextStep", dict(action_mode="residual", tier="hard", task="track_random")),
    ("NextStep", dict(action_mode="actuators", observe_error_integral=True, action_rate_penalty=0.1)),
    ("SameStep", dict(action_mode="virtual", tier="wind")),
    ("Disabled", dict(action_mode="actuators", tier="noisy")),
])
def test_threaded_step_equals_the_serial_step(autoreset_mode, kw):
    """A batch split over threads writes its autoresets and gathers its outputs (observation, reward, flags,
    infos) in each thread's range right after the physics (without training aids; with them, after the
    kernel): the same results, bit for bit, as the whole batch stepped in one call, across episode ends."""
    from softpvtol_gym._parallel import thread_count

    n = 600
    envs = [SoftPVTOLVectorEnv(num_envs=n, autoreset_mode=autoreset_mode, max_episode_seconds=0.05, **kw)
            for _ in range(2)]
    if thread_count() > 1:
        assert len(envs[0].sim._ranges) > 1
    envs[1].sim._ranges = [(0, n)]  # the serial path
    # and a few sub-envs against single envs (the same seeds), across NextStep's autoresets
    singles = {i: SoftPVTOLEnv(max_episode_seconds=0.05, **kw) for i in (0, 63, 64, 301, n - 1)}
    need_reset = dict.fromkeys(singles, False)
    first = [e.reset(seed=4) for e in envs]
    _assert_same_outputs(first[0], first[1], "reset")
    for i, e in singles.items():
        np.testing.assert_array_equal(first[0][0][i], e.reset(seed=4 + i)[0])
    rng = np.random.default_rng(2)
    ends = 0
    for k in range(12):
        a = rng.uniform(-1.3, 1.3, envs[0].action_space.shape)
        out = [e.step(a) for e in envs]
        for i, name in enumerate(("obs", "rewards", "terminated", "truncated", "infos")):
            _assert_same_outputs(out[0][i], out[1][i], f"step {k} {name}")
        if autoreset_mode == "NextStep":
            for i, e in singles.items():
                if need_reset[i]:
                    o, info = e.reset()
                    r, term, trunc = 0.0, False, False
                    need_reset[i] = False
                else:
                    o, r, term, trunc, info = e.step(a[i])
                    need_reset[i] = term or trunc
                np.testing.assert_array_equal(out[0][0][i], o)
                assert (out[0][1][i], out[0][2][i], out[0][3][i]) == (r, term, trunc)
                assert out[0][4]["time"][i] == info["time"]
                assert out[0][4]["termination_reason"][i] == info.get("termination_reason")
        done = out[0][2] | out[0][3]
        ends += int(done.sum())
        if autoreset_mode == "Disabled" and done.any():
            again = [e.reset(options={"reset_mask": done}) for e in envs]
            _assert_same_outputs(again[0], again[1], f"reset_mask after step {k}")
    assert ends >= n  # every sub-env's episode (5 steps) ended at least once


def test_run_split_side_error_propagates_without_running_after():
    """``side()`` raising in a split step: every range still runs fn (the physics of every row), none runs
    ``after`` (it would use what side() prepares), and the error reaches the caller once every thread is done."""
    from softpvtol_gym._parallel import run_split

    done, after = [], []

    def side():
        raise RuntimeError("side failed")

    ranges = [(0, 1), (1, 2), (2, 3), (3, 4)]
    with pytest.raises(RuntimeError, match="side failed"):
        run_split(lambda lo, hi: done.append(lo), ranges, side, lambda lo, hi: after.append(lo))
    assert after == [] and sorted(done) == [0, 1, 2, 3]
    done.clear()
    run_split(lambda lo, hi: done.append(lo), ranges, None, lambda lo, hi: after.append(lo))
    assert sorted(after) == [0, 1, 2, 3] and sorted(done) == [0, 1, 2, 3]
