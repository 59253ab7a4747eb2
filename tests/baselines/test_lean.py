"""The lean inference path of learned policies (:class:`LeanMLPPolicy`): the actions of SB3's ``model.predict`` to
1e-5 (committed checkpoints on observations of real episodes; every algorithm and actor variant SB3 builds for
this env), each row's action the same bit for bit whatever the batch, and the evaluator's episodes the same
alone or in a batch for every kind of policy. Also :func:`compute_us_single`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, compute_us_single, run_episodes
from softpvtol_gym.baselines.training.lean import LeanMLPPolicy
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from tests.conftest import RESULTS, RUNS_DIR

#: committed checkpoints: residual and actuators modes, and 21 observations (the error integrals observed)
CHECKPOINTS = {
    "residual": RUNS_DIR / "ppo_residual_track_random_nominal" / "seed_0",
    "actuators": RUNS_DIR / "ppo_actuators_hover_nominal" / "seed_0",
    "integral-obs": RESULTS / "ablation_runs" / "ppo-residual-integral-gated-iobs_track_random_hard" / "seed_0",
}
TOLERANCE = 1e-5


def episode_observations(policy, action_mode: str, task: str, tier: str, env_kwargs=None, n_envs: int = 4,
                         steps: int = 100, seed: int = EVAL_SEED_OFFSET) -> np.ndarray:
    """The observations (n_envs * steps, obs_dim) of ``policy``'s own closed loop on real episodes."""
    env = SoftPVTOLVectorEnv(num_envs=n_envs, action_mode=action_mode, task=task, tier=tier, **(env_kwargs or {}))
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        out.append(obs.copy())
        obs = env.step(policy.predict(obs, deterministic=True)[0])[0]
    return np.concatenate(out)


@pytest.fixture(scope="module")
def committed():
    """name -> (torch LearnedPolicy, its RunConfig, observations of its episodes on the hard tier)."""
    out = {}
    for name, path in CHECKPOINTS.items():
        policy, config = LearnedPolicy.load(path, inference="torch")
        obs = episode_observations(policy, config.action_mode, config.task, "hard", config.eval_env_kwargs())
        out[name] = (policy, config, obs)
    return out


@pytest.fixture(scope="module")
def actuator_observations():
    """Observations of real actuators-mode episodes (the passivity controller on track_random, hard tier)."""
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="track_random")
    return episode_observations(PassivityPolicy.from_env(probe), "actuators", "track_random", "hard", steps=80)


# ------------------------------------------------------------------------------------ the same actions as torch
@pytest.mark.parametrize("name", list(CHECKPOINTS))
def test_lean_acts_as_torch_on_committed_checkpoints(committed, name):
    policy, _, obs = committed[name]
    assert policy.vecnorm is not None and policy.vecnorm.norm_obs  # normalised observations
    lean = LeanMLPPolicy.from_sb3(policy.model, policy.vecnorm)
    assert lean.normalized and lean.ops == ("linear", "tanh", "linear", "tanh", "linear")
    theirs = policy.model.predict(policy.vecnorm.normalize_obs(obs.astype(np.float32)), deterministic=True)[0]
    mine = lean.predict(obs)[0]
    assert mine.shape == theirs.shape == (len(obs), lean.action_dim) and mine.dtype == theirs.dtype == np.float32
    assert len(obs) >= 400 and theirs.std(axis=0).min() > 1e-3  # several hundred distinct actions
    assert np.abs(mine - theirs).max() <= TOLERANCE
    # one observation (obs_dim,) gives one action (action_dim,)
    np.testing.assert_array_equal(lean.predict(obs[7])[0], mine[7])


def _sb3_models(env):
    """(label, model) of every actor SB3 builds for this env with an MlpPolicy: PPO and A2C (with gSDE, with and
    without its squashing), SAC (with gSDE: Hardtanh then tanh), TD3, DDPG, ReLU and deeper networks."""
    import torch
    from stable_baselines3 import A2C, DDPG, PPO, SAC, TD3

    relu = {"activation_fn": torch.nn.ReLU, "net_arch": [32, 16, 8]}
    specs = [("ppo", PPO, {}), ("a2c", A2C, {}), ("ppo-relu", PPO, {"policy_kwargs": relu}),
             ("ppo-gsde", PPO, {"use_sde": True}),
             ("ppo-gsde-squash", PPO, {"use_sde": True, "policy_kwargs": {"squash_output": True}}),
             ("sac", SAC, {}), ("sac-gsde", SAC, {"use_sde": True}),
             ("sac-small", SAC, {"policy_kwargs": {"net_arch": [7]}}),
             ("td3", TD3, {}), ("ddpg", DDPG, {})]
    out = []
    for label, cls, kw in specs:
        torch.manual_seed(0)
        model = cls("MlpPolicy", env, seed=0, device="cpu", **kw)
        if label.startswith("ppo") or label == "a2c":  # PPO's action_net starts near 0: spread its actions out
            with torch.no_grad():
                model.policy.action_net.weight.mul_(30.0)
        out.append((label, model))
    return out


def test_lean_acts_as_torch_for_every_algorithm(actuator_observations):
    from stable_baselines3.common.vec_env import VecNormalize

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = VecNormalize(SoftPVTOLSB3VecEnv(num_envs=1, action_mode="actuators", task="track_random"), training=False,
                       norm_reward=False, clip_obs=3.0)
    rng = np.random.default_rng(0)
    dim = env.observation_space.shape[0]
    env.obs_rms.mean, env.obs_rms.var = rng.normal(size=dim), rng.uniform(0.01, 2.0, size=dim)
    obs = actuator_observations
    assert (np.abs(env.normalize_obs(obs)) == 3.0).any()  # the clip is exercised
    models = dict(_sb3_models(env))
    for label, model in models.items():
        lean = LeanMLPPolicy.from_sb3(model, env)
        theirs = model.predict(env.normalize_obs(obs), deterministic=True)[0]
        mine = lean.predict(obs)[0]
        assert np.abs(mine - theirs).max() <= TOLERANCE, label
        assert theirs.std(axis=0).min() > 1e-3, label
        if label in ("sac-gsde", "ppo-gsde-squash"):
            assert lean.squash and lean.ops[-1] == "tanh", label
    assert LeanMLPPolicy.from_sb3(models["sac-gsde"], env).ops[-3:] == ("linear", "hardtanh", "tanh")
    assert LeanMLPPolicy.from_sb3(models["td3"], env).ops[-2:] == ("linear", "tanh")


@pytest.mark.parametrize("k", [1, 3])
def test_lean_stacks_frames_as_vec_frame_stack(k):
    """Raw observations through the lean path = the model's predict on VecFrameStack(VecNormalize)'s
    observations, step by step across autoresets (episodes of 0.1 s: 10 steps)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = SoftPVTOLSB3VecEnv(num_envs=2, action_mode="residual", task="track_random", max_episode_seconds=0.1)
    vecnorm = VecNormalize(env, training=False, norm_reward=False)
    rng = np.random.default_rng(0)
    vecnorm.obs_rms.mean = rng.normal(size=env.observation_space.shape[0])
    stacked = VecFrameStack(vecnorm, n_stack=k)
    model = PPO("MlpPolicy", stacked, n_steps=16, batch_size=16, seed=0, device="cpu")
    lean = LearnedPolicy(model, vecnorm).lean
    assert lean.frame_stack == k
    wrapped = stacked.reset()
    starts, dones_seen = np.ones(2, bool), 0
    for _ in range(30):
        mine = lean.predict(vecnorm.get_original_obs(), episode_start=starts)[0]
        theirs = model.predict(wrapped, deterministic=True)[0]
        assert np.abs(mine - theirs).max() <= TOLERANCE
        wrapped, _, dones, _ = stacked.step(theirs)
        starts = dones.copy()
        dones_seen += int(dones.sum())
    assert dones_seen >= 4


def test_lean_computes_the_documented_function():
    """A small network from plain arrays against the same function written in numpy (float64): VecNormalize's
    normalisation (float32 rounding, the clip), linear layers, tanh, relu, hardtanh; clip or unscale."""
    rng = np.random.default_rng(3)
    w1, b1, w2, b2 = rng.normal(size=(6, 4)), rng.normal(size=6), rng.normal(size=(2, 6)), rng.normal(size=2)
    mean, var = rng.normal(size=4), rng.uniform(0.1, 2.0, size=4)
    obs = rng.normal(scale=4.0, size=(50, 4)).astype(np.float32)
    low, high = np.array([-1.0, 0.0]), np.array([2.0, 0.5])
    x = np.clip((obs - mean) / np.sqrt(var + 1e-8), -2.5, 2.5).astype(np.float32).astype(np.float64)
    hidden = np.maximum(np.tanh(x @ w1.T + b1), 0.0)
    y = np.clip(hidden @ w2.T + b2, -0.8, 0.8)
    ops = [("linear", w1, b1), ("tanh",), ("relu",), ("linear", w2, b2), ("hardtanh", -0.8, 0.8)]
    for squash, want in ((False, np.clip(y, low, high)), (True, low + 0.5 * (y + 1.0) * (high - low))):
        lean = LeanMLPPolicy(ops, low, high, squash, obs_mean=mean, obs_var=var, clip_obs=2.5,
                             action_dtype=np.float64)
        np.testing.assert_allclose(lean.predict(obs)[0], want, rtol=1e-12, atol=1e-12)
    plain = LeanMLPPolicy(ops[:2], -np.ones(6), np.ones(6), False, action_dtype=np.float64)  # the float32 obs
    np.testing.assert_allclose(plain.predict(obs[:, :4])[0], np.tanh(obs.astype(np.float64) @ w1.T + b1),
                               rtol=1e-12, atol=1e-12)


def _summed_in_order(weight, bias, x):
    """A linear layer as the lean pass documents it, in plain Python floats: output j is 0.0 plus
    weight[j, k] * x[k] for k = 0, 1, ... in turn, then plus bias[j] (IEEE double, no fused multiply-add)."""
    out = []
    for j in range(weight.shape[0]):
        acc = 0.0
        for k in range(weight.shape[1]):
            acc = acc + float(weight[j, k]) * float(x[k])
        out.append(acc + float(bias[j]))
    return np.array(out)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lean_layers_sum_each_output_in_input_order_bit_for_bit(dtype):
    """The compiled pass (vectorised across outputs) against the layer summed in order in plain Python: the same
    bits, for a torch model's float32 weights (kept as float32) and for float64 weights (kept as given)."""
    rng = np.random.default_rng(11)
    w1, b1 = (rng.normal(size=(37, 19)) * 0.3).astype(dtype), rng.normal(size=37)
    w2, b2 = (rng.normal(size=(3, 37)) * 0.3).astype(dtype), rng.normal(size=3)
    obs = rng.normal(size=(20, 19)).astype(np.float32)
    lean = LeanMLPPolicy([("linear", w1, b1), ("tanh",), ("linear", w2, b2)], -np.full(3, np.inf),
                         np.full(3, np.inf), False, action_dtype=np.float64)
    for row, got in zip(obs, lean.predict(obs)[0]):
        hidden = [math.tanh(v) for v in _summed_in_order(w1, b1, row.astype(np.float64))]  # libm, as the kernel
        np.testing.assert_array_equal(got, _summed_in_order(w2, b2, hidden))


def test_the_compiled_frame_stack_is_the_readable_stack_bit_for_bit():
    """The stacks updated inside the compiled pass against the readable reference: VecNormalize's normalisation in
    numpy, :class:`ObservationStack` (VecFrameStack's update) and the unstacked lean policy on its rows; the same bits,
    over sub-envs whose episodes start at different steps."""
    from softpvtol_gym.baselines.training.stacking import ObservationStack

    rng = np.random.default_rng(5)
    k, dim, n = 3, 5, 4
    w1, b1, w2, b2 = rng.normal(size=(8, k * dim)), rng.normal(size=8), rng.normal(size=(2, 8)), rng.normal(size=2)
    mean, var = rng.normal(size=dim), rng.uniform(0.1, 2.0, size=dim)
    ops = [("linear", w1, b1), ("tanh",), ("linear", w2, b2)]
    low, high = -np.full(2, 3.0), np.full(2, 3.0)
    lean = LeanMLPPolicy(ops, low, high, False, obs_mean=mean, obs_var=var, clip_obs=2.5, frame_stack=k,
                         action_dtype=np.float64)
    stack = ObservationStack(k, k * dim)
    unstacked = LeanMLPPolicy(ops, low, high, False, action_dtype=np.float64)  # on the stacked rows, unnormalised
    for step in range(12):
        obs = rng.normal(scale=3.0, size=(n, dim)).astype(np.float32)
        starts = np.ones(n, bool) if step == 0 else rng.random(n) < 0.2
        normed = np.clip((obs - mean) / np.sqrt(var + 1e-8), -2.5, 2.5).astype(np.float32)
        want = unstacked.predict(stack.push(normed, starts))[0]
        np.testing.assert_array_equal(lean.predict(obs, episode_start=starts)[0], want)


# ------------------------------------------------------------------------------------ batch invariance
def test_a_rows_action_does_not_depend_on_the_batch(committed):
    """The same observation alone and inside batches of 1, 7 and 64 (any position) gets the same action, bit
    for bit; torch's float32 forward does not promise it."""
    policy, _, obs = committed["residual"]
    lean = LeanMLPPolicy.from_sb3(policy.model, policy.vecnorm)
    obs = obs[:64]
    alone = np.stack([lean.predict(o)[0] for o in obs])
    for size in (1, 7, 64):
        batched = np.concatenate([lean.predict(obs[i:i + size])[0] for i in range(0, len(obs), size)])
        np.testing.assert_array_equal(batched, alone)
    shuffled = np.random.default_rng(0).permutation(len(obs))
    np.testing.assert_array_equal(lean.predict(obs[shuffled])[0], alone[shuffled])


def _alone_and_in_a_batch(policy, action_mode, task, tier, env_kwargs=None, batch: int = 5, picks=(0, 3)):
    """Episodes ``picks`` of a batch of ``batch`` from seed s, and the same episodes run alone from seed s + i."""
    seed = EVAL_SEED_OFFSET
    together = run_episodes(policy, action_mode, task, tier, batch, seed, env_kwargs=env_kwargs)
    alone = [run_episodes(policy, action_mode, task, tier, 1, seed + i, env_kwargs=env_kwargs)[0] for i in picks]
    return [together[i] for i in picks], alone


@pytest.mark.parametrize("loop, task, tier", [
    ("bounded", "track_random", "hard"),  # the passivity controller, the env's default loop
    ("integral", "track_random", "hard"),  # with integral action (controller memory per episode)
    ("extended", "hover", "nominal"),  # the dynamically extended loop (a policy of its own)
])
def test_analytic_episodes_are_the_same_alone_and_in_a_batch(loop, task, tier):
    kw = {"allocation": "exact", "controller_loop": loop}
    policy = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=task, **kw))
    in_batch, alone = _alone_and_in_a_batch(policy, "actuators", task, tier, kw)
    assert in_batch == alone
    assert in_batch[0] != in_batch[1]  # different episodes, compared one to one
    assert not any(e["crashed"] for e in alone)


def test_learned_episodes_are_the_same_alone_and_in_a_batch(committed):
    """The lean path (LearnedPolicy's default): an episode's metrics do not depend on the batch it ran in."""
    _, config, _ = committed["residual"]
    policy, _ = LearnedPolicy.load(CHECKPOINTS["residual"])
    assert policy.inference == "lean" and policy.lean is not None
    in_batch, alone = _alone_and_in_a_batch(policy, config.action_mode, config.task, "nominal",
                                            config.eval_env_kwargs())
    assert in_batch == alone
    assert in_batch[0] != in_batch[1]
    assert all(e["rms_position_error_steady"] is not None for e in alone)


# ------------------------------------------------------------------------------------ LearnedPolicy, the command
def test_learned_policy_picks_its_inference(committed):
    policy, _, obs = committed["actuators"]
    assert policy.inference == "torch" and policy.lean is None
    lean = LearnedPolicy(policy.model, policy.vecnorm)
    assert lean.inference == "lean"
    assert np.abs(lean.predict(obs[:50])[0] - policy.predict(obs[:50])[0]).max() <= TOLERANCE
    with pytest.raises(ValueError, match=r"inference must be one of \['lean', 'torch'\], got 'fast'"):
        LearnedPolicy(policy.model, policy.vecnorm, inference="fast")
    with pytest.raises(ValueError, match="deterministic action only, got deterministic=False"):
        lean.predict(obs[:2], deterministic=False)
    with pytest.raises(ValueError, match=r"observations must be an array of shape \(18,\) or \(n, 18\) with n >= 1, "
                                         r"got shape \(3, 17\)"):
        lean.predict(obs[:3, :17])


def _with(obs, index, value):
    bad = obs.astype(np.float64)
    bad[index] = value
    return bad


@pytest.mark.parametrize("inference", ["lean", "torch"])
@pytest.mark.parametrize("make, message", [
    (lambda o: _with(o, 3, np.nan), r"must be finite \(as float32\), got nan at 3"),
    (lambda o: _with(o, 0, np.inf), r"must be finite \(as float32\), got inf at 0"),
    (lambda o: _with(o, 5, 1e300), r"must be finite \(as float32\), got 1e\+300 at 5"),
    (lambda o: np.stack([o, _with(o, 2, -np.inf)]), r"got -inf at \(1, 2\)"),
    (lambda o: np.zeros((0, 18)), r"with n >= 1, got shape \(0, 18\)"),
    (lambda o: o.astype(complex), r"\(real numbers\), got complex values \(dtype complex128\)"),
    (lambda o: o > 0, r"\(real numbers\), got bool values \(dtype bool\)"),
    (lambda o: [str(v) for v in o], r"\(real numbers\), got str values \(dtype <U"),
    (lambda o: [[1.0], [1.0, 2.0]], r"\(real numbers\), got \[\[1.0\], \[1.0, 2.0\]\]"),
])
def test_learned_policies_refuse_observations_they_cannot_act_on(committed, inference, make, message):
    policy, _, obs = committed["actuators"]
    learned = LearnedPolicy(policy.model, policy.vecnorm, inference=inference)
    with pytest.raises(ValueError, match=message):
        learned.predict(make(obs[0]))
    assert np.isfinite(learned.predict(obs[0])[0]).all()  # a good one still acts


def test_evaluate_command_takes_inference(tmp_path, committed):
    from softpvtol_gym.baselines.commands.evaluate import main

    out = {}
    for inference in ("lean", "torch"):
        path = tmp_path / f"{inference}.json"
        assert main(["--policy", str(CHECKPOINTS["actuators"]), "--episodes", "1", "--inference", inference,
                     "--json", str(path)]) == 0
        out[inference] = json.loads(path.read_text())["summary"]
    assert out["lean"]["mean_return"] == pytest.approx(out["torch"]["mean_return"], rel=1e-3)


def test_unsupported_models_are_refused_naming_what_and_the_way_out():
    import torch
    from stable_baselines3 import PPO

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    env = SoftPVTOLSB3VecEnv(num_envs=1, action_mode="actuators", task="hover")
    model = PPO("MlpPolicy", env, device="cpu", policy_kwargs={"activation_fn": torch.nn.ELU})
    with pytest.raises(ConfigError, match=r"got the module ELU; use LearnedPolicy\(\.\.\., inference='torch'\)"):
        LearnedPolicy(model)
    assert LearnedPolicy(model, inference="torch").predict(np.zeros(18, np.float32))[0].shape == (4,)


@pytest.mark.parametrize("ops, message", [
    ([], r"starting with \('linear', weight, bias\), got \[\]"),
    ([("tanh",)], r"starting with \('linear', weight, bias\), got \['tanh'\]"),
    (["linear"], r"operation 0 must be a tuple \('name', arguments\.\.\.\), got 'linear'"),
    ([("linear", np.ones((2, 3)), None), ("linear", np.ones((2, 4)), None)], r"operation 1: the weight must be a "
                                                                             r"matrix \(out, 2\), got shape \(2, 4\)"),
    ([("linear", np.ones((2, 3)), None), ("sigmoid",)], r"operation 1: expected .* got 'sigmoid' with 0 arguments"),
    ([("linear", np.full((2, 3), np.nan), None)], "operation 0: the weight holds non-finite values"),
    ([("linear", np.ones((2, 3)), np.ones(3))], r"operation 0's bias must be a vector of 2 entries, got shape \(3,\)"),
    ([("linear", np.ones((2, 3)), None), ("hardtanh", 1.0, -1.0)], r"hardtanh needs min <= max, got \(1.0, -1.0\)"),
])
def test_bad_networks_are_refused_naming_the_operation(ops, message):
    with pytest.raises(ValueError, match=message):
        LeanMLPPolicy(ops, -np.ones(2), np.ones(2), False)


def test_bad_settings_are_refused():
    ops = [("linear", np.ones((2, 4)), None)]
    with pytest.raises(ValueError, match="obs_mean and obs_var go together"):
        LeanMLPPolicy(ops, -np.ones(2), np.ones(2), False, obs_mean=np.zeros(4))
    with pytest.raises(ValueError, match=r"obs_var must be a vector of 4 entries, got shape \(3,\)"):
        LeanMLPPolicy(ops, -np.ones(2), np.ones(2), False, obs_mean=np.zeros(4), obs_var=np.ones(3))
    with pytest.raises(ValueError, match="not a multiple of frame_stack=3"):
        LeanMLPPolicy(ops, -np.ones(2), np.ones(2), False, frame_stack=3)
    with pytest.raises(ValueError, match="action_low must be <= action_high"):
        LeanMLPPolicy(ops, np.ones(2), -np.ones(2), False)
    with pytest.raises(ValueError, match=r"action_high must be a vector of 2 entries, got shape \(3,\)"):
        LeanMLPPolicy(ops, -np.ones(2), np.ones(3), False)
    with pytest.raises(ValueError, match="action_high must be finite"):
        LeanMLPPolicy(ops, -np.ones(2), np.array([1.0, np.inf]), True)  # squashed: mapped onto the bounds
    with pytest.raises(ValueError, match="action_low must be free of NaN"):
        LeanMLPPolicy(ops, np.array([np.nan, 0.0]), np.ones(2), False)
    unbounded = LeanMLPPolicy(ops, np.full(2, -np.inf), np.full(2, np.inf), False, action_dtype=np.float64)
    np.testing.assert_array_equal(unbounded.predict(np.full(4, 3.0))[0], [12.0, 12.0])


# ------------------------------------------------------------------------------------ compute_us_single
class _Recorder:
    """A policy that records how it is called."""

    def __init__(self):
        self.calls = []

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        self.calls.append((np.shape(observation), None if episode_start is None else list(episode_start)))
        return np.zeros(5, np.float32), state


def test_compute_us_single_times_one_observation_at_a_time_in_one_torch_thread():
    import torch

    obs = np.zeros((4, 18))
    recorder = _Recorder()
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        us = compute_us_single(recorder, obs, repeats=2)
        assert torch.get_num_threads() == 2  # restored
    finally:
        torch.set_num_threads(before)
    assert us > 0 and np.isfinite(us)
    # the untimed call, then each pass in order, starting the robot's memory anew on its first observation
    start, step = ((18,), [True]), ((18,), None)
    assert recorder.calls == [start] + [start, step, step, step] * 2


class _ActionRecorder:
    """A policy that records the actions another policy gives."""

    def __init__(self, policy):
        self.policy, self.actions = policy, []

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        action, state = self.policy.predict(observation, state, episode_start, deterministic)
        self.actions.append(np.array(action, dtype=np.float64).reshape(-1))
        return action, state


def test_the_per_robot_compute_pass_replays_the_closed_loop_of_a_controller_with_memory():
    """The integral loop (an integrator: memory) does in each timed pass what it did in its episode: the pass
    replays the episode's observations in order from a fresh start, so every action is the episode's."""
    from softpvtol_gym.baselines.evaluation import episode_observations

    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="track_random", controller_loop="integral")
    recorder = _ActionRecorder(PassivityPolicy.from_env(probe))
    obs = episode_observations(recorder, "actuators", "track_random", "wind", EVAL_SEED_OFFSET, steps=60)
    assert obs.shape == (60, 18)
    in_episode, recorder.actions = np.array(recorder.actions), []
    compute_us_single(recorder, obs, repeats=2)
    replayed = np.array(recorder.actions[1:]).reshape(2, 60, -1)  # after the untimed call: two passes
    np.testing.assert_array_equal(replayed[0], in_episode)
    np.testing.assert_array_equal(replayed[1], in_episode)
    assert np.abs(in_episode - in_episode[0]).max() > 0  # the actions do change along the episode


@pytest.mark.parametrize("obs, repeats, message", [
    (np.zeros(18), 1, r"observations must be an array \(n, obs_dim\) of n >= 1 observations, got shape \(18,\)"),
    (np.zeros((0, 18)), 1, r"got shape \(0, 18\)"),
    (np.zeros((2, 18)), 0, "repeats must be an integer >= 1, got 0"),
    (np.zeros((2, 18)), True, "repeats must be an integer >= 1, got True"),
])
def test_compute_us_single_refuses_bad_input(obs, repeats, message):
    with pytest.raises(ValueError, match=message):
        compute_us_single(_Recorder(), obs, repeats=repeats)


def test_compute_us_single_measures_the_real_policies(committed):
    """Every kind runs on one observation (obs_dim,) at a time (no timing asserted: it depends on the load)."""
    policy, config, obs = committed["actuators"]
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover", controller_loop="integral")
    for p in (PassivityPolicy.from_env(probe), LearnedPolicy(policy.model, policy.vecnorm), policy):
        assert compute_us_single(p, obs[:20], repeats=1) > 0
