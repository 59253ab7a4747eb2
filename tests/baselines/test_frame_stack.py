"""the training plumbing: frame stacking (hyperparameter ``frame_stack``, SB3's VecFrameStack in
training, the same stack in :class:`LearnedPolicy` for evaluation, recorded in the checkpoint's config) and
env options of a run (``RunConfig.env_options``, ``train.py --env``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from softpvtol_gym.baselines.commands.train import main as train_main
from softpvtol_gym.baselines.config.hyperparams import ENV_OPTION_KEYS, frame_stack, parse_env_options
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.config.validation import validate_hyperparams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, run_episodes, summarize
from softpvtol_gym.baselines.training.loop import train
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from tests.conftest import TINY


def _stacked_setup(k: int, n_envs: int, seconds: float):
    """A PPO model on VecFrameStack(VecNormalize(adapter), k) with non-trivial frozen statistics, and the
    wrappers. Episodes of ``seconds`` (short: autoresets within a few dozen steps)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = SoftPVTOLSB3VecEnv(num_envs=n_envs, action_mode="residual", task="track_random",
                             max_episode_seconds=seconds)
    vecnorm = VecNormalize(env, training=False, norm_reward=False)
    rng = np.random.default_rng(0)
    dim = env.observation_space.shape[0]
    vecnorm.obs_rms.mean = rng.normal(size=dim)
    vecnorm.obs_rms.var = rng.uniform(0.5, 2.0, size=dim)
    stacked = VecFrameStack(vecnorm, n_stack=k)
    model = PPO("MlpPolicy", stacked, n_steps=16, batch_size=16, seed=0, device="cpu")
    return model, vecnorm, stacked, env


@pytest.mark.parametrize("k", [2, 4])
def test_stacked_predict_feeds_the_model_what_vec_frame_stack_feeds_it(k):
    """Raw observations of the native env through LearnedPolicy (normalise, then stack per sub-env, reset on
    episode_start) give the model exactly the arrays SB3's VecFrameStack over VecNormalize gives it in
    training, across autoresets (episodes of 0.2 s: 20 steps, so the 70 steps cross three of them), and
    the same actions."""
    model, vecnorm, stacked, env = _stacked_setup(k, n_envs=3, seconds=0.2)
    policy = LearnedPolicy(model, vecnorm)
    assert policy.frame_stack == k  # read from the model's VecFrameStack
    stacked.seed(7)
    wrapped_obs = stacked.reset()
    starts = np.ones(3, bool)  # SB3's _last_episode_starts at the first step
    rng = np.random.default_rng(1)
    n_dones = 0
    for _ in range(70):
        raw = vecnorm.get_original_obs()
        mine = policy.stacked(vecnorm.normalize_obs(raw.astype(np.float32)), starts)
        np.testing.assert_array_equal(mine, wrapped_obs)
        if starts.any():  # a fresh stack: zeros, then the first observation
            dim = raw.shape[1]
            assert not mine[starts, :-dim].any() and mine[starts, -dim:].any()
        wrapped_obs, _, dones, _ = stacked.step(rng.uniform(-1, 1, size=(3, env.action_space.shape[0])))
        starts = dones.copy()
        n_dones += int(dones.sum())
    assert n_dones >= 6  # the comparison crossed autoresets in every sub-env


def test_stacked_predict_gives_the_actions_of_the_model_on_the_wrapper_observations():
    """predict on raw observations = the model's predict on VecFrameStack's observations, step by step (the torch
    path: the same calls, so the same actions; the lean path is held to 1e-5 in test_lean.py)."""
    model, vecnorm, stacked, env = _stacked_setup(3, n_envs=2, seconds=0.1)
    policy = LearnedPolicy(model, vecnorm, inference="torch")
    wrapped_obs = stacked.reset()
    starts = np.ones(2, bool)
    for _ in range(30):
        mine = policy.predict(vecnorm.get_original_obs(), episode_start=starts, deterministic=True)[0]
        np.testing.assert_array_equal(mine, model.predict(wrapped_obs, deterministic=True)[0])
        wrapped_obs, _, dones, _ = stacked.step(mine)
        starts = dones.copy()


def test_episode_start_empties_only_that_sub_envs_stack():
    model, vecnorm, _, _ = _stacked_setup(3, n_envs=2, seconds=1.0)
    policy = LearnedPolicy(model, vecnorm, frame_stack=3)
    dim = model.observation_space.shape[0] // 3
    a, b, c = (np.full((2, dim), v, np.float32) for v in (1.0, 2.0, 3.0))
    policy.stacked(a, [True, True])
    policy.stacked(b, [False, False])
    out = policy.stacked(c, [False, True])
    np.testing.assert_array_equal(out[0], np.concatenate([a[0], b[0], c[0]]))
    np.testing.assert_array_equal(out[1], np.concatenate([np.zeros(dim), np.zeros(dim), c[1]]))
    with pytest.raises(ValueError, match="pass episode_start all true"):
        policy.stacked(np.zeros((3, dim), np.float32), [False, False, False])  # another number of sub-envs
    with pytest.raises(ValueError, match="3 stacked observations"):
        policy.stacked(np.zeros((2, dim + 1), np.float32), [True, True])
    with pytest.raises(ValueError, match=r"episode_start must hold one bool per sub-env \(2\), got shape \(3,\)"):
        policy.stacked(c, [False, True, True])
    with pytest.raises(ValueError, match="frame_stack must be an integer >= 1"):
        LearnedPolicy(model, vecnorm, frame_stack=0)


def test_without_episode_start_the_first_call_starts_the_stacks_and_later_calls_continue_them():
    model, vecnorm, _, _ = _stacked_setup(3, n_envs=2, seconds=1.0)
    dim = model.observation_space.shape[0] // 3
    a, b = (np.full((2, dim), v, np.float32) for v in (1.0, 2.0))
    for inference in ("torch", "lean"):
        policy = LearnedPolicy(model, vecnorm, inference=inference)
        policy.stacked(a, None)
        np.testing.assert_array_equal(policy.stacked(b, None)[0], np.concatenate([np.zeros(dim), a[0], b[0]]))
        # predict without episode_start: the second call sees both observations (the first is not forgotten)
        fresh = LearnedPolicy(model, vecnorm, inference=inference)
        fresh.predict(a)
        continued = fresh.predict(b)[0]
        fresh.reset_stack()
        np.testing.assert_array_equal(fresh.predict(b)[0], fresh.predict(b, episode_start=[True, True])[0])
        assert not np.array_equal(continued, fresh.predict(b, episode_start=[True, True])[0])


@pytest.mark.parametrize("bad", [0, -1, 1.5, "a", True, 65])
def test_bad_frame_stack_is_rejected_with_a_clear_message(bad):
    with pytest.raises(ConfigError, match=r"hyperparameter frame_stack must be an integer >= 1 and <= 64, got"):
        validate_hyperparams("ppo", {"frame_stack": bad})


def test_bad_frame_stack_on_the_command_line_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        train_main(["--hp", "frame_stack=0", "--out", str(tmp_path / "x"), "--no-progress-bar"])
    assert exc.value.code == 2 and "frame_stack must be an integer >= 1" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _tiny_config(**kw) -> RunConfig:
    hp = {"policy": "MlpPolicy", "normalize": True, "n_steps": 32, "batch_size": 32, "n_epochs": 2, **kw.pop("hp", {})}
    return RunConfig(task="track_random", timesteps=256, n_envs=4, hyperparams=hp, checkpoint_freq=128,
                     eval_freq=10**6, eval_episodes=2, **kw)


def test_frame_stack_survives_save_and_load_and_resume(tmp_path):
    """A run with frame_stack=3 records it (config.yaml of the checkpoint); the loaded policy stacks 3
    observations and acts as the trained one; a resumed run continues bit for bit (the stack is part of the
    resume state)."""
    from safetensors.torch import load_file

    cfg = _tiny_config(hp={"frame_stack": 3})
    run = train(cfg, tmp_path / "ref")
    policy, loaded_cfg = LearnedPolicy.load(tmp_path / "ref")
    assert policy.frame_stack == 3 and frame_stack(loaded_cfg.hyperparams) == 3
    assert yaml.safe_load((tmp_path / "ref" / "config.yaml").read_text())["hyperparams"]["frame_stack"] == 3
    assert policy.model.observation_space.shape[0] == 3 * run["vecnorm"].observation_space.shape[0]
    trained = LearnedPolicy(run["model"], run["vecnorm"])
    assert trained.frame_stack == 3
    eps = [summarize(run_episodes(p, "residual", "track_random", "nominal", 3, EVAL_SEED_OFFSET))
           for p in (trained, policy)]
    assert eps[0] == eps[1]
    # the in-training evaluation (same policy, same episodes) agrees with a loaded policy's
    last = json.loads((tmp_path / "ref" / "evaluations.json").read_text())[-1]
    again = summarize(run_episodes(policy, "residual", "track_random", "nominal", 2, EVAL_SEED_OFFSET + cfg.seed,
                                   env_kwargs=loaded_cfg.eval_env_kwargs()))
    assert last["mean_return"] == again["mean_return"]
    # exact resume: 128 steps, then --resume to 256, equals the uninterrupted run
    half = _tiny_config(hp={"frame_stack": 3})
    half.timesteps = 128
    train(half, tmp_path / "resumed")
    train(cfg, tmp_path / "resumed", resume=True)
    a, b = load_file(tmp_path / "ref" / "model.safetensors"), load_file(tmp_path / "resumed" / "model.safetensors")
    assert sorted(a) == sorted(b)
    for key in a:
        assert (a[key] == b[key]).all(), key


def test_a_run_without_frame_stack_is_k_1(tiny_run):
    policy, config = LearnedPolicy.load(tiny_run)
    assert "frame_stack" not in config.hyperparams and frame_stack(config.hyperparams) == 1
    assert policy.frame_stack == 1


# ------------------------------------------------------------------------------------ env options
def test_env_options_are_parsed_without_eval():
    assert parse_env_options(["residual_scale=0.4", "residual_space=actuators"]) == \
        {"residual_scale": 0.4, "residual_space": "actuators"}
    assert parse_env_options(["residual_scale=1"]) == {"residual_scale": 1}
    assert parse_env_options(["residual_scale=1e-1"]) == {"residual_scale": 0.1}
    with pytest.raises(ConfigError, match="key=value"):
        parse_env_options(["residual_scale"])
    with pytest.raises(ConfigError, match=r"unknown env option 'tier'; a run may set \['residual_scale'"):
        parse_env_options(["tier=hard"])
    assert set(ENV_OPTION_KEYS) == {"residual_scale", "residual_space", "residual_base", "residual_gate",
                                    "observe_error_integral", "error_integral_limit", "error_integral_error_limit"}
    assert parse_env_options(["error_integral_error_limit=0.5"]) == {"error_integral_error_limit": 0.5}
    assert parse_env_options(["observe_error_integral=true", "residual_gate=0.1"]) == \
        {"observe_error_integral": True, "residual_gate": 0.1}


@pytest.mark.parametrize("options, message", [
    ({"residual_scale": -0.1}, "env option residual_scale: residual_scale must be finite and > 0"),
    ({"residual_scale": 0}, "env option residual_scale: residual_scale must be finite and > 0"),
    ({"residual_scale": "big"}, "env option residual_scale: residual_scale must be a real number"),
    ({"residual_scale": True}, "env option residual_scale: residual_scale must be a real number"),
    ({"residual_space": "joints"}, "env option residual_space: residual_space must be one of"),
    ({"frame_skip": 2}, "unknown env option 'frame_skip'"),
    ([("residual_scale", 0.4)], "env_options must be a mapping"),
])
def test_bad_env_options_are_config_errors_naming_the_key(options, message):
    with pytest.raises(ConfigError, match=message):
        RunConfig(env_options=options)


def test_env_options_need_the_residual_mode():
    with pytest.raises(ConfigError, match="acts on the residual action mode only"):
        RunConfig(action_mode="actuators", env_options={"residual_scale": 0.4})


def test_env_options_reach_training_and_evaluation_envs_and_legacy_configs_have_none(tmp_path):
    c = RunConfig(env_options={"residual_scale": 0.4})
    assert c.env_kwargs()["residual_scale"] == 0.4 and c.eval_env_kwargs()["residual_scale"] == 0.4
    assert RunConfig().env_options == {} and "residual_scale" not in RunConfig().env_kwargs()
    path = tmp_path / "config.yaml"
    c.save(path)
    assert RunConfig.load(path) == c
    legacy = c.to_dict()
    del legacy["env_options"]
    path.write_text(yaml.safe_dump(legacy))
    assert RunConfig.load(path).env_options == {}
    with pytest.raises(ConfigError, match="lacks the keys"):  # only a saved (strict) config may omit fields
        RunConfig.from_dict({k: v for k, v in legacy.items() if k != "seed"}, strict=True)


def test_a_run_trained_with_residual_scale_0_4_evaluates_with_0_4(tmp_path):
    """train.py --env residual_scale=0.4: the training env, the in-training evaluation, the final comparison
    and a loaded checkpoint all use 0.4 (on the default scale the same policy gives other episodes)."""
    from softpvtol_gym.baselines.training.models import make_env

    out = tmp_path / "run"
    assert train_main(["--task", "track_random", "--timesteps", "256", *TINY, "--env", "residual_scale=0.4",
                       "--out", str(out)]) == 0
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["env_options"] == {"residual_scale": 0.4}
    policy, config = LearnedPolicy.load(out)
    assert config.env_options == {"residual_scale": 0.4} and config.eval_env_kwargs()["residual_scale"] == 0.4
    assert make_env(config, 1).config.residual_scale == 0.4
    kw = config.eval_env_kwargs()
    mine = summarize(run_episodes(policy, "residual", "track_random", "nominal", 1, EVAL_SEED_OFFSET, env_kwargs=kw))
    result = json.loads((out / "result.json").read_text())
    assert result["ppo"]["summary"] == mine
    assert json.loads((out / "evaluations.json").read_text())[-1]["mean_return"] == mine["mean_return"]
    default = summarize(run_episodes(policy, "residual", "track_random", "nominal", 1, EVAL_SEED_OFFSET,
                                     env_kwargs={"controller_loop": config.controller_loop}))
    assert default["mean_return"] != mine["mean_return"]
    # a resume may not change the options
    with pytest.raises(SystemExit) as exc:
        train_main(["--out", str(out), "--resume", "--env", "residual_scale=0.2", "--timesteps", "512",
                    "--no-progress-bar"])
    assert exc.value.code == 2


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_learned_policy_acts_as_the_models_own_predict(algo):
    """LearnedPolicy.predict (inference="torch") skips SB3's per-call set_training_mode but otherwise makes SB3's
    calls: the same actions as model.predict (batched and single observations; SAC squashes, PPO clips), also
    right after a training update left the policy in training mode."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecNormalize

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = VecNormalize(SoftPVTOLSB3VecEnv(num_envs=4, action_mode="residual", task="track_random"))
    model = (PPO("MlpPolicy", env, n_steps=16, batch_size=32, seed=0, device="cpu") if algo == "ppo"
             else SAC("MlpPolicy", env, learning_starts=0, batch_size=32, seed=0, device="cpu"))
    model.learn(64)
    policy = LearnedPolicy(model, env, inference="torch")
    raw = np.random.default_rng(0).normal(scale=3.0, size=(6, env.observation_space.shape[0])).astype(np.float32)
    normed = env.normalize_obs(raw)
    for deterministic in (True, False):
        model.policy.set_training_mode(True)
        torch.manual_seed(1)
        mine, _ = policy.predict(raw, deterministic=deterministic)
        assert not model.policy.training
        torch.manual_seed(1)
        theirs, _ = model.predict(normed, deterministic=deterministic)
        np.testing.assert_array_equal(mine, theirs)
        assert mine.shape == (6, 5)
    one, _ = policy.predict(raw[0], deterministic=True)
    np.testing.assert_array_equal(one, model.predict(normed[0], deterministic=True)[0])
    assert one.shape == (5,)
