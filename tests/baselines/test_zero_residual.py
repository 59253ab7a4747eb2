"""The zero-at-zero residual policy: its action is exactly 0 at zero tracking error, in torch and on the lean path,
and the safe checkpoint format rebuilds it."""

from __future__ import annotations

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLVectorEnv
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.lean import LeanMLPPolicy
from softpvtol_gym.envs.observation import N_ERROR_INTEGRALS, OBS_DIM
from tests.conftest import TINY

torch = pytest.importorskip("torch")


def _model(observe_error_integral: bool):
    """A PPO ZeroAtZeroPolicy on the residual mode with VecNormalize statistics of a few random steps, its weights
    perturbed (so that nothing is zero by chance), and observations of those steps."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from softpvtol_gym.baselines.training.zero_residual import ZeroAtZeroPolicy
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = SoftPVTOLSB3VecEnv(num_envs=4, action_mode="residual", task="track_random",
                             observe_error_integral=observe_error_integral)
    vecnorm = VecNormalize(env)
    model = PPO(ZeroAtZeroPolicy, vecnorm, seed=0, n_steps=16, batch_size=16)
    rng = np.random.default_rng(0)
    raw = []
    vecnorm.reset()
    for _ in range(30):
        vecnorm.step(rng.uniform(-0.3, 0.3, (4, env.action_space.shape[0])).astype(np.float32))
        raw.append(vecnorm.get_original_obs().copy())
    with torch.no_grad():
        for p in model.policy.parameters():
            p.add_(0.3 * torch.randn_like(p))
    vecnorm.training = False
    model.policy.set_zero_error(vecnorm)
    return model, vecnorm, np.concatenate(raw)


def _torch_mean(model, vecnorm, raw: np.ndarray) -> np.ndarray:
    obs = torch.as_tensor(vecnorm.normalize_obs(raw))
    with torch.no_grad():
        return model.policy.get_distribution(obs).distribution.mean.numpy()


@pytest.mark.parametrize("observe_error_integral", [False, True])
def test_the_action_is_exactly_zero_at_zero_error_in_torch_and_on_the_lean_path(observe_error_integral):
    model, vecnorm, raw = _model(observe_error_integral)
    errors = model.policy.error_index
    integrals = list(range(OBS_DIM, OBS_DIM + N_ERROR_INTEGRALS)) if observe_error_integral else []
    assert errors.tolist() == [0, 1, 2, *integrals]
    lean = LeanMLPPolicy.from_sb3(model, vecnorm)
    at_zero = raw.copy()
    at_zero[:, errors] = 0.0
    assert np.any(at_zero != raw)  # the observations had errors
    assert np.all(_torch_mean(model, vecnorm, at_zero) == 0.0)
    assert np.all(lean.predict(at_zero)[0] == 0.0)
    # away from zero error the correction is not zero, and the two paths agree to float32 rounding
    mean = _torch_mean(model, vecnorm, raw)
    assert np.abs(mean).max() > 1e-3
    low, high = model.action_space.low, model.action_space.high
    np.testing.assert_allclose(lean.predict(raw)[0], np.clip(mean, low, high), atol=2e-5)
    # one error entry away from 0 is enough for a correction; the velocities are part of the state, not the error
    one = at_zero.copy()
    one[:, 1] = 0.05
    assert np.abs(lean.predict(one)[0]).max() > 0.0


def test_the_correction_is_smooth_at_zero_error():
    """g(s, e) - g(s, 0) with g smooth: the action grows linearly from 0 along an error direction."""
    model, vecnorm, raw = _model(False)
    lean = LeanMLPPolicy.from_sb3(model, vecnorm)
    base = raw[:1].copy()
    base[:, :3] = 0.0
    steps = np.array([1e-4, 2e-4, 4e-4])
    acts = []
    for h in steps:
        obs = base.copy()
        obs[0, 0] = h
        acts.append(lean.predict(obs)[0][0])
    acts = np.array(acts)
    assert np.abs(acts).max() > 0
    np.testing.assert_allclose(acts[1], 2 * acts[0], rtol=2e-2, atol=1e-9)
    np.testing.assert_allclose(acts[2], 4 * acts[0], rtol=4e-2, atol=1e-9)


def test_a_trained_run_rebuilds_the_policy_from_its_checkpoint(tmp_path):
    from softpvtol_gym.baselines.commands.train import main
    from softpvtol_gym.baselines.training.policy import LearnedPolicy
    from softpvtol_gym.baselines.training.zero_residual import ZeroAtZeroPolicy

    out = tmp_path / "run"
    argv = ["--timesteps", "256", *TINY, "--task", "track_random", "--hp", "policy=ZeroAtZeroPolicy",
            "--env", "observe_error_integral=true", "--out", str(out)]
    assert main(argv) == 0
    torch_policy, config = LearnedPolicy.load(out, inference="torch")
    lean_policy, _ = LearnedPolicy.load(out)
    assert isinstance(torch_policy.model.policy, ZeroAtZeroPolicy)
    assert config.hyperparams["policy"] == "ZeroAtZeroPolicy"

    env = SoftPVTOLVectorEnv(num_envs=3, action_mode="residual", task="track_random", observe_error_integral=True)
    obs, _ = env.reset(seed=5)
    at_zero = obs.copy()
    at_zero[:, torch_policy.model.policy.error_index] = 0.0
    assert np.all(lean_policy.predict(at_zero)[0] == 0.0)
    assert np.all(torch_policy.predict(at_zero)[0] == 0.0)
    np.testing.assert_allclose(lean_policy.predict(obs)[0], torch_policy.predict(obs)[0], atol=2e-5)
    assert np.abs(lean_policy.predict(obs)[0]).max() > 0


@pytest.mark.parametrize("argv, words", [
    (["--algo", "sac", "--hp", "policy=ZeroAtZeroPolicy"], "is a PPO policy"),
    ([*TINY, "--hp", "policy=ZeroAtZeroPolicy", "--hp", "frame_stack=2"], "a frame stack is not supported"),
    ([*TINY, "--hp", "policy=CnnPolicy"], "'ZeroAtZeroPolicy'"),
])
def test_bad_settings_name_the_problem(argv, words, tmp_path, capsys):
    from softpvtol_gym.baselines.commands.train import main

    with pytest.raises((SystemExit, ConfigError)) as exc:
        main(["--timesteps", "64", "--no-progress-bar", *argv, "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err + (str(exc.value) if isinstance(exc.value, ConfigError) else "")
    assert words in err, err
