"""The fast paths of the env's Python side, each checked against its readable reference: the reset
uniforms drawn in a compiled loop, and the info dicts built from a slice of the packed state."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
from gymnasium.utils import seeding

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.envs.info import FLAG_ENTRIES, FLOAT_ENTRIES, INFO_KEYS, batch_info, single_info
from softpvtol_gym.envs.packed_state import SI, S
from softpvtol_gym.envs.reward import REWARD_TERMS
from softpvtol_gym.envs.uniforms import UniformDraws, python_draws


def _generators(n, seed=0):
    return [seeding.np_random(seed + i)[0] for i in range(n)]


@pytest.mark.parametrize("rows", [[0], [1, 3, 5], list(range(0, 40, 3)), list(range(40))])
def test_compiled_draws_equal_the_python_loop_and_advance_the_same_streams(rows):
    fast, ref = _generators(40), _generators(40)
    draws = UniformDraws()
    idx = np.array(rows, dtype=np.int64)
    for _ in range(3):  # consecutive draws continue the same streams
        np.testing.assert_array_equal(draws.draw(fast, idx, 23), python_draws(ref, idx, 23))
    for g, h in zip(fast, ref):  # every generator left exactly where the Python loop leaves it
        assert g.bit_generator.state == h.bit_generator.state


def test_compiled_draws_follow_a_replaced_generator_after_invalidate():
    fast, ref = _generators(16), _generators(16)
    draws = UniformDraws()
    idx = np.arange(16)
    draws.draw(fast, idx, 5), python_draws(ref, idx, 5)
    fast[3], ref[3] = seeding.np_random(99)[0], seeding.np_random(99)[0]
    draws.invalidate()
    np.testing.assert_array_equal(draws.draw(fast, idx, 5), python_draws(ref, idx, 5))
    new_list = _generators(16, seed=7)  # another list: its own states, no invalidate needed
    np.testing.assert_array_equal(draws.draw(new_list, idx, 5), python_draws(_generators(16, seed=7), idx, 5))


def test_generators_that_are_not_pcg64_take_the_python_loop():
    fast = [np.random.Generator(np.random.MT19937(i)) for i in range(12)]
    ref = [np.random.Generator(np.random.MT19937(i)) for i in range(12)]
    idx = np.arange(12)
    np.testing.assert_array_equal(UniformDraws().draw(fast, idx, 9), python_draws(ref, idx, 9))


def test_vector_env_copies_draw_from_their_own_generators():
    env = SoftPVTOLVectorEnv(num_envs=32)
    env.reset(seed=5)
    idx = np.arange(32)
    twin = copy.deepcopy(env)
    restored = pickle.loads(pickle.dumps(env))
    want = python_draws(copy.deepcopy(env._rngs), idx, 11)
    np.testing.assert_array_equal(twin._draw(idx)[:, :11], want)
    np.testing.assert_array_equal(restored._draw(idx)[:, :11], want)
    np.testing.assert_array_equal(env._draw(idx)[:, :11], want)  # the original's streams untouched by its copies


def _reference_info(sim, n, reason):
    """The info of entry n read from the whole packed state (the readable reference)."""
    f = sim.F[n]
    info = {"reward_terms": {k: float(f[S.terms + i]) for i, k in enumerate(REWARD_TERMS)}}
    info.update({k: float(f[c]) for k, c in FLOAT_ENTRIES})
    info.update({k: bool(f[c] > 0.5) for k, c in FLAG_ENTRIES})
    info.update(action_clipped=bool(sim.I[n, SI.clipped]), termination_reason=reason, time=float(f[S.t]))
    return info


def test_info_dicts_equal_the_reference_read_from_the_whole_state():
    env = SoftPVTOLEnv(task="track_random", tier="hard")
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(30):
        _, _, term, trunc, info = env.step(rng.uniform(-1.2, 1.2, 4))
        assert info == _reference_info(env.sim, 0, info["termination_reason"])
        # (the single env writes its info as one dict display: the keys in the tables' order)
        assert list(info) == list(INFO_KEYS) and list(info["reward_terms"]) == list(REWARD_TERMS)
        assert single_info(env.sim, None) == _reference_info(env.sim, 0, None)
        if term or trunc:
            env.reset()
    venv = SoftPVTOLVectorEnv(num_envs=7, task="track_random", tier="hard")
    venv.reset(seed=2)
    for _ in range(5):
        venv.step(rng.uniform(-1.2, 1.2, (7, 4)))
    infos = batch_info(venv.sim)
    for n in range(7):
        ref = _reference_info(venv.sim, n, None)
        assert {k: float(v[n]) for k, v in infos["reward_terms"].items()} == ref["reward_terms"]
        for k, _ in FLOAT_ENTRIES + (("time", None),):
            assert float(infos[k][n]) == ref[k]
        for k, _ in FLAG_ENTRIES:
            assert bool(infos[k][n]) == ref[k]
    venv.sim.F[:] = 0.0  # the info holds copies, not views of the state
    assert infos["time"].max() > 0.0 and max(v.max() for v in infos["reward_terms"].values()) > 0.0


def _kernel_timings():
    """benchmarks/kernel_timings.py as a module (a script, not a package module)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "kernel_timings.py"
    spec = importlib.util.spec_from_file_location("kernel_timings", path)
    timings = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(timings)
    return timings


def test_the_reset_draws_timing_runs(capsys):
    assert _kernel_timings().main(["draws"]) == 0
    out = capsys.readouterr().out
    assert "compiled loop" in out and "Python loop" in out


def test_the_timings_of_the_kernel_parts_and_the_lanes_run(capsys):
    """``kernel_timings.py parts`` and ``simd`` call the step kernel's private parts and the lane kernels by name:
    they still run (their figures are not checked), and the parts add up to about the kernel they split."""
    import re

    timings = _kernel_timings()
    timings.time_simd(reps=3)
    timings.time_parts(reps=3)
    out = capsys.readouterr().out
    assert "RK4 step, full lane block (SIMD)" in out and "libm sin and cos" in out
    for part in ("actions clipped", "RK4 step (lanes, SIMD)", "observation", "reward"):
        assert f"  {part}" in out
    together, kernel = (float(x) for x in re.search(r"together: (\d+) us; the kernel \(step_physics_rows\): (\d+) us",
                                                     out).groups())
    assert 0.5 * kernel < together < 2.0 * kernel


def test_single_env_steps_every_float_array_as_its_float64_values():
    """The single env copies a float array of shape (A,) into its kernel's buffer; other inputs (lists, strided
    views, the wrong shape) take the general path: the same trajectory for the same values, and the buffer holds
    nothing from one step to the next (a NaN action is refused, and the next step is as if it never came)."""
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.2, 1.2, (40, 4)).astype(np.float16).astype(np.float64)  # exact in every dtype
    envs = [SoftPVTOLEnv(task="track_random", tier="noisy") for _ in range(5)]
    for e in envs:
        e.reset(seed=7)
    wide = np.zeros((40, 8))
    wide[:, ::2] = actions
    for k, a in enumerate(actions):
        given = (a, a.astype(np.float32), a.astype(np.float16), wide[k, ::2], a.tolist())
        out = [e.step(x) for e, x in zip(envs, given)]
        for o in out[1:]:
            np.testing.assert_array_equal(o[0], out[0][0])
            assert o[1:] == out[0][1:]
        if k == 20:
            with pytest.raises(ValueError, match="action must be finite"):
                envs[1].step(np.array([np.nan, 0, 0, 0], np.float32))
            with pytest.raises(ValueError, match=r"action must have shape \(4,\)"):
                envs[1].step(np.zeros(5, np.float32))
        if out[0][2] or out[0][3]:
            break


@pytest.mark.parametrize("loop", [None, "integral", "extended"])
def test_policy_predict_of_one_observation_equals_the_batch_of_one(loop):
    """PassivityPolicy / ExtendedPolicy.predict of one float observation (18,) takes a short path once the batch
    size is 1: the same actions, bit for bit, as the general path (the same observations as (1, 18) batches),
    along an episode, across an episode start, and the same error for an observation it cannot act on."""
    from softpvtol_gym import PassivityPolicy

    env = SoftPVTOLEnv(task="track_random", tier="noisy")
    short, general = PassivityPolicy.from_env(env, loop=loop), PassivityPolicy.from_env(env, loop=loop)
    obs, _ = env.reset(seed=4)
    for k in range(60):
        start = k == 30  # an episode start: the general path for both, then the short path again
        a, _ = short.predict(obs.astype(np.float64) if k % 3 == 0 else obs, episode_start=True if start else None)
        b, _ = general.predict(obs[None, :].astype(np.float64), episode_start=np.array([start]) if start else None)
        assert a.shape == (env.action_space.shape[0],) and a.dtype == np.float32
        np.testing.assert_array_equal(a, b[0])
        obs, _, term, trunc, _ = env.step(a)
        assert not (term or trunc)
    bad = obs.copy()
    bad[5] = 7.0  # q_l beyond 2 pi
    for policy, x in ((short, bad), (general, bad[None, :])):
        with pytest.raises(ValueError, match=r"observation index 5 \(q_l\) = 7\.0 is outside the model's validity"):
            policy.predict(x)
    bad[5] = np.nan
    with pytest.raises(ValueError, match="observation must be finite"):
        short.predict(bad)


@pytest.mark.parametrize("loop", [None, "extended"])
def test_a_copied_policy_acts_as_the_original(loop):
    """A policy copied (pickle, deepcopy) after acting on single observations acts as the original from there
    on: its one-observation buffer (views of itself) is rebuilt, not copied into independent arrays."""
    from softpvtol_gym import PassivityPolicy

    env = SoftPVTOLEnv(task="track_random")
    policy = PassivityPolicy.from_env(env, loop=loop)
    obs, _ = env.reset(seed=2)
    for _ in range(5):
        obs = env.step(policy.predict(obs)[0])[0]
    clones = [pickle.loads(pickle.dumps(policy)), copy.deepcopy(policy)]
    for _ in range(5):
        a = policy.predict(obs)[0]
        for c in clones:
            np.testing.assert_array_equal(c.predict(obs)[0], a)
        obs = env.step(a)[0]
