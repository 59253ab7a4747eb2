"""The hyperparameter files are keyed by env id in rl-baselines3-zoo's format, train.py and
``python -m rl_zoo3.train`` read the same files, and the per-mode env ids behave as SoftPVTOL-v0 with the
mode fixed."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import softpvtol_gym  # noqa: F401  (registers the ids)
from softpvtol_gym.baselines.config.hyperparams import (
    HYPERPARAMS_DIR,
    algo_kwargs,
    hyperparams_key,
    load_hyperparams,
    normalize_kwargs,
)
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.config.validation import validate_hyperparams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.envs import ACTION_MODES, ENV_ID, MODE_ENV_IDS

ROOT = Path(__file__).resolve().parents[2]
#: the keys rl-baselines3-zoo 2.x takes out of an entry before passing the rest to the algorithm
#: (ExperimentManager._preprocess_hyperparams / _preprocess_normalization)
ZOO_KEYS = {"n_envs", "n_timesteps", "normalize", "env_wrapper", "vec_env_wrapper", "frame_stack", "callback",
            "env_kwargs", "monitor_kwargs"}


# ---------------------------------------------------------------------------------------- ids
@pytest.mark.parametrize("mode", ACTION_MODES)
def test_per_mode_ids_are_softpvtol_with_the_mode_fixed(mode):
    env_id = MODE_ENV_IDS[mode]
    single = gym.make(env_id, task="setpoint")
    ref = gym.make(ENV_ID, action_mode=mode, task="setpoint")
    assert single.unwrapped.config == ref.unwrapped.config
    assert single.action_space == ref.action_space and single.observation_space == ref.observation_space
    a, b = single.reset(seed=3)[0], ref.reset(seed=3)[0]
    np.testing.assert_array_equal(a, b)
    action = single.action_space.sample()
    np.testing.assert_array_equal(single.step(action)[0], ref.step(action)[0])
    vec = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    assert vec.unwrapped.config.action_mode == mode and vec.num_envs == 3
    assert gym.make(env_id, action_mode=mode).unwrapped.config.action_mode == mode  # the same mode: fine
    other = next(m for m in ACTION_MODES if m != mode)
    for make in (lambda: gym.make(env_id, action_mode=other),
                 lambda: gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", action_mode=other)):
        with pytest.raises(ValueError, match=f"{env_id} has action_mode='{mode}'; got action_mode='{other}'"):
            make()


def test_softpvtol_v0_keeps_its_defaults():
    assert gym.make(ENV_ID).unwrapped.config.action_mode == "actuators"
    assert gym.make(ENV_ID, action_mode="residual").unwrapped.config.action_mode == "residual"


# ------------------------------------------------------------------------------- YAML files
@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_hyperparameter_files_are_keyed_by_registered_env_ids(algo):
    table = yaml.safe_load((HYPERPARAMS_DIR / f"{algo}.yml").read_text())  # rl_zoo3 reads it with safe_load
    assert set(table) == {ENV_ID, *MODE_ENV_IDS.values()}
    for env_id in table:
        assert env_id in gym.registry
    assert table[ENV_ID] == table[MODE_ENV_IDS["actuators"]]  # SoftPVTOL-v0 is the actuators mode
    for mode in ACTION_MODES:
        assert hyperparams_key(mode) == MODE_ENV_IDS[mode]
        assert load_hyperparams(algo, mode) == table[MODE_ENV_IDS[mode]]  # what train.py uses


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_every_key_is_valid_for_rl_zoo3_and_for_train_py(algo):
    from stable_baselines3 import PPO, SAC

    params = set(inspect.signature({"ppo": PPO, "sac": SAC}[algo].__init__).parameters) - {"self", "env"}
    table = yaml.safe_load((HYPERPARAMS_DIR / f"{algo}.yml").read_text())
    for env_id, entry in table.items():
        unknown = set(entry) - ZOO_KEYS - params
        assert not unknown, (env_id, unknown)
        assert isinstance(entry["n_timesteps"], int) and isinstance(entry["policy"], str)
        # rl_zoo3 evaluates policy_kwargs; train.py parses it without eval: both give the same dict
        if "policy_kwargs" in entry:
            assert algo_kwargs(entry)["policy_kwargs"] == eval(entry["policy_kwargs"], {"dict": dict})
        validate_hyperparams(algo, entry)


def test_normalize_is_read_as_rl_zoo3_reads_it():
    assert normalize_kwargs({"normalize": True, "gamma": 0.98}) == {"gamma": 0.98}
    assert normalize_kwargs({"normalize": "dict(norm_obs=True, norm_reward=False)", "gamma": 0.9}) == {
        "norm_obs": True, "norm_reward": False, "gamma": 0.9}
    assert normalize_kwargs({"normalize": {"norm_reward": False}}) == {"norm_reward": False}
    assert normalize_kwargs({"normalize": True}) == {} and normalize_kwargs({"normalize": {}}) == {}  # normalised
    assert normalize_kwargs({"normalize": False}) is None and normalize_kwargs({}) is None
    with pytest.raises(ConfigError, match="differs from the entry's gamma"):
        validate_hyperparams("ppo", {"normalize": {"gamma": 0.9}, "gamma": 0.99})
    with pytest.raises(ConfigError, match="normalize must be"):
        validate_hyperparams("ppo", {"normalize": "dict(norm_obs=print)"})
    with pytest.raises(ConfigError, match="unknown"):
        validate_hyperparams("ppo", {"normalize": {"norm_ob": True}})
    RunConfig(hyperparams={"normalize": "dict(norm_obs=True)", "gamma": 0.99})


def test_an_unknown_entry_names_the_mode_and_the_entries(tmp_path):
    (tmp_path / "ppo.yml").write_text("SoftPVTOL-v0: {policy: MlpPolicy}\n")
    with pytest.raises(ConfigError, match=r"no entry 'SoftPVTOLResidual-v0' \(the residual mode\); entries: "
                                          r"\['SoftPVTOL-v0'\]"):
        load_hyperparams("ppo", "residual", directory=tmp_path)


# ------------------------------------------------------------------------------- rl_zoo3 itself
@pytest.mark.slow  # rl_zoo3 in a subprocess (about 15 s)
@pytest.mark.parametrize("env_id", [ENV_ID, MODE_ENV_IDS["residual"]])
def test_rl_zoo3_trains_from_the_hyperparameter_file(env_id, tmp_path):
    """The command (with a tiny budget and small rollouts)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", env_id, "--gym-packages", "softpvtol_gym",
           "--conf-file", str(HYPERPARAMS_DIR / "ppo.yml"), "-n", "256", "--eval-freq", "-1", "--seed", "0",
           "--log-folder", str(tmp_path), "--hyperparams", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "Hyperparameters not found" not in proc.stdout + proc.stderr
    run = tmp_path / "ppo" / f"{env_id}_1"
    assert (run / f"{env_id}.zip").stat().st_size > 0
    saved = (run / env_id / "config.yml").read_text()  # the entry the zoo used, with our policy_kwargs
    assert "log_std_init" in saved and "n_timesteps" in saved


def test_linear_schedules_are_read_as_rl_zoo3_reads_them():
    """``learning_rate: lin_<x>`` (and clip_range): x at the start of training, linearly down to 0 at its end."""
    kwargs = algo_kwargs({"learning_rate": "lin_4e-3", "clip_range": "lin_0.2", "n_epochs": 5})
    for key, start in (("learning_rate", 4e-3), ("clip_range", 0.2)):
        schedule = kwargs[key]
        assert schedule(1.0) == pytest.approx(start) and schedule(0.5) == pytest.approx(start / 2)
        assert schedule(0.0) == pytest.approx(0.0)
    assert kwargs["n_epochs"] == 5
    validate_hyperparams("ppo", {"learning_rate": "lin_4e-3", "clip_range": "lin_0.2"})
    for bad in ("lin_", "lin_-1", "lin_inf", "lin_abc", "exp_1e-3", "4e-3x"):
        with pytest.raises(ConfigError, match="learning_rate must be a finite number > 0 or a linear schedule"):
            validate_hyperparams("ppo", {"learning_rate": bad})
