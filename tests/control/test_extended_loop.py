"""The extended loop: exact tracking in continuous time (the error is RK4's O(dt^4), not a floor
proportional to dt), the held implementation, the policy in the env, and bad input.

The full 80 s study is benchmarks/extended_loop.py (its committed JSON backs the docs' table, re-checked
here); these are short versions with faster error dynamics, so that the transient is over in 12 s.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from softpvtol_gym import ExtendedPolicy, PassivityPolicy, SoftPVTOLEnv, SoftPVTOLParams
from softpvtol_gym.control import LOOPS, PassivityController, simulate_closed_loop
from softpvtol_gym.control.extended import ExtendedController, ExtendedGains, simulate_extended_loop
from softpvtol_gym.control.references import paper_reference
from softpvtol_gym.envs.config import EnvConfig

ROOT = Path(__file__).resolve().parents[2]
FAST = ExtendedGains(position=(81.0, 108.0, 54.0, 12.0), attitude=(25.0, 10.0), sigma=(100.0, 20.0))  # (s+3)^4, ...
Q0 = (0.3, 6.8, 0.1, 0.05, -0.02)  # near the paper's reference at t = 0 (x 0, z 7)


def _tail_error(r, t0):
    m = r["t"] >= t0
    return float(np.abs(r["q"][m, :2] - r["q_ref"][m, :2]).max())


def test_loops_lists_extended_and_the_passivity_controller_refuses_it():
    assert LOOPS["extended"]["allocation"] == "exact"
    with pytest.raises(ValueError, match="not a PassivityController loop"):
        PassivityController.from_loop("extended")


def test_continuous_time_error_is_the_integrators_not_a_floor_proportional_to_dt():
    """hold="stage": the error after the transient shrinks like dt^4 (RK4), not like dt."""
    errs = {dt: _tail_error(simulate_extended_loop(gains=FAST, q0=Q0, t_final=14.0, dt=dt), 12.0)
            for dt in (0.02, 0.01)}
    assert errs[0.01] < 1e-9, errs
    assert errs[0.02] / errs[0.01] > 8.0, errs  # 16 for dt^4; a floor proportional to dt gives 2


def test_sigma_converges_and_the_body_point_follows_the_centre_of_mass():
    r = simulate_closed_loop("extended", q0=Q0, t_final=14.0, dt=0.01, gains=FAST)
    m = r["t"][:-1] >= 12.0
    assert np.abs(r["outputs"][m, 3]).max() < 1e-12  # sigma = q_l + q_r
    assert np.abs(r["outputs"][m, 0:2] - r["q"][:-1][m, 0:2]).max() < 1e-12  # y = p when sigma = 0
    assert not r["degenerate"].any() and r["thrust_state"][:, 0].min() > 0


@pytest.mark.parametrize("held_command, ratio", [("midpoint", (3.0, 6.0)), ("start", (1.5, 3.0))])
def test_held_command_error_order(held_command, ratio):
    """hold="step" (the env's zero-order hold): the command held over a step is the law's at the step's
    predicted midpoint (the default), whose error is O(dt^2): halving dt quarters it; the law's at the
    step's start leaves O(dt)."""
    errs = {dt: _tail_error(simulate_extended_loop(q0=Q0, t_final=10.0, dt=dt, hold="step", gains=FAST,
                                                   held_command=held_command), 9.0) for dt in (0.01, 0.005)}
    assert errs[0.01] < 1e-3, errs
    assert ratio[0] < errs[0.01] / errs[0.005] < ratio[1], errs


def test_committed_study_backs_the_docs():
    data = json.loads((ROOT / "benchmarks" / "extended_loop.json").read_text())
    cells = data["simulation"]["cells"]
    assert cells["stage 0.01"]["worst_max_abs_xz"] <= 1e-8
    assert cells["stage 0.005"]["worst_max_abs_xz"] < cells["stage 0.01"]["worst_max_abs_xz"] / 8.0
    assert all(c["degenerate_steps"] == 0 for c in cells.values())
    import importlib.util

    from softpvtol_gym.baselines.util import blocks

    spec = importlib.util.spec_from_file_location("softpvtol_extended_loop", ROOT / "benchmarks" / "extended_loop.py")
    extended_loop = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(extended_loop)  # the table in docs/control.md is the generated one

    paper = json.loads((ROOT / "results/paper_reproduction/metrics.json").read_text())
    bounded = paper["steady_state"]["loops"]["bounded"]
    # held over each step: O(dt^2), and below the bounded loop's
    assert cells["step 0.005"]["worst_max_abs_xz"] < cells["step 0.01"]["worst_max_abs_xz"] / 3.0
    assert cells["step 0.01"]["worst_max_abs_xz"] < bounded["step"]["0.01"]["worst_max_abs_xz"] / 10.0
    env = data["env"]
    assert env["extended"]["end"] == "time limit" and env["extended"]["saturated_step_share"] == 0.0
    assert env["extended"]["rms_position_30_40s"] < env["bounded"]["rms_position_30_40s"]
    table = extended_loop.table(data, bounded)
    for page in (ROOT / "docs" / "control.md", ROOT / "README.md"):
        assert blocks.read_block(extended_loop.BLOCK, extended_loop.SOURCE, page) == table
    assert blocks.read_block(extended_loop.ENV_BLOCK, extended_loop.SOURCE, ROOT / "docs" / "control.md") == \
        extended_loop.env_table(data)


def test_controller_memory_is_the_extension_and_resets():
    c = ExtendedController(dt=0.01)
    q_ref, qd_ref, qdd_ref, q3, q4 = paper_reference(0.0, order=4)
    q = np.array(Q0)
    c(q, np.zeros(5), q_ref, qd_ref, qdd_ref, q3, q4)
    xi1 = c.thrust_state.copy()
    assert xi1.shape == (1, 2) and xi1[0, 0] > 0
    c(q, np.zeros(5), q_ref, qd_ref, qdd_ref, q3, q4, commit=False)
    assert np.array_equal(c.thrust_state, xi1)
    c.reset()
    assert c.thrust_state is None
    with pytest.raises(ValueError, match="batch of 1"):
        c(q, np.zeros(5), q_ref, qd_ref, qdd_ref)
        c(np.stack([q, q]), np.zeros(5), q_ref, qd_ref, qdd_ref)


def test_a_midpoint_predicted_outside_the_model_holds_the_start_command():
    # a diverging episode: the arms at 3 rad bending at 1000 rad/s would be predicted past pi at the step's
    # midpoint; the held command is then the law at the step's start (the model is not evaluated out of range)
    q_ref, qd_ref, qdd_ref, q3, q4 = paper_reference(0.0, order=4)
    q, qd = np.array([[0.1, 0.2, 0.1, 3.0, -0.2]]), np.array([[0.0, 0.0, 0.0, 1000.0, 0.0]])
    xi = np.array([[70.0, 0.0]])
    ref = np.stack([r.reshape(1, 5) for r in (q_ref, qd_ref, qdd_ref, q3, q4)])
    mid, _ = ExtendedController(dt=0.01).held_step(q, qd, xi, ref)
    start, _ = ExtendedController(dt=0.01, held_command="start").held_step(q, qd, xi, ref)
    np.testing.assert_array_equal(mid.actuators, start.actuators)


@pytest.mark.parametrize("kwargs, match", [
    (dict(params=SoftPVTOLParams(m_r=1.5)), "equal arms"),
    (dict(params=SoftPVTOLParams(l_l=0.4)), "equal arms"),
    (dict(dt=0.0), "dt must be"),
    (dict(min_thrust=-1.0), "min_thrust"),
    (dict(initial_thrust=0.0), "initial_thrust"),
    (dict(input_map="printed"), "input_map"),
    (dict(held_command="end"), "held_command"),
])
def test_bad_controller_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ExtendedController(**kwargs)


def test_passivity_gains_are_not_extended_gains():
    from softpvtol_gym.control import PassivityGains

    with pytest.raises(ValueError, match="ExtendedGains"):
        ExtendedController(gains=PassivityGains())
    with pytest.raises(ValueError, match="ExtendedGains"):
        simulate_closed_loop("extended", gains=PassivityGains(), t_final=0.1)


@pytest.mark.parametrize("field, value", [("position", (1.0, 1.0, 1.0, 1.0)), ("attitude", (1.0, -1.0)),
                                          ("sigma", (1.0,)), ("position", "abcd")])
def test_gains_must_be_hurwitz(field, value):
    with pytest.raises(ValueError, match=f"ExtendedGains.{field}"):
        ExtendedGains(**{field: value})


def test_bad_inputs_to_the_step_and_the_simulation():
    c = ExtendedController()
    q_ref, qd_ref, qdd_ref = paper_reference(0.0)
    with pytest.raises(ValueError, match="q contains NaN"):
        c(np.array([np.nan, 0, 0, 0, 0]), np.zeros(5), q_ref, qd_ref, qdd_ref)
    with pytest.raises(ValueError, match=r"qdot must have shape"):
        c(np.zeros(5), np.zeros(4), q_ref, qd_ref, qdd_ref)
    with pytest.raises(ValueError, match="third and fourth derivatives"):
        simulate_closed_loop("extended", reference=lambda t: paper_reference(t), t_final=0.1)
    with pytest.raises(ValueError, match="hold must be"):
        simulate_closed_loop("extended", hold="ramp", t_final=0.1)
    with pytest.raises(ValueError, match="order must be"):
        paper_reference(0.0, order=3)


def test_non_positive_thrust_is_safeguarded_and_reported():
    """The decoupling divides by T: an extension at or below 0 is evaluated with ``min_thrust`` (finite
    commands) and reported in ``degenerate``; the thrust split itself uses the extension's value."""
    c = ExtendedController()
    jet = np.stack([np.zeros((2, 5))] * 5)
    xi = np.array([[0.0, -3.0], [70.0, 0.0]])
    out = c.evaluate(np.zeros((2, 5)), np.zeros((2, 5)), xi, jet)
    assert out.degenerate.tolist() == [True, False]
    assert np.isfinite(out.actuators).all() and np.isfinite(out.thrust_accel).all()
    assert out.actuators[0, 0] + out.actuators[0, 1] == pytest.approx(0.0)


def test_env_refuses_extended_as_residual_base_and_policy_dispatches():
    with pytest.raises(ValueError, match="not available as the residual mode's base controller"):
        EnvConfig(action_mode="residual", controller_loop="extended")
    env = SoftPVTOLEnv(action_mode="actuators", task="track_paper", controller_loop="extended")
    assert isinstance(PassivityPolicy.from_env(env), ExtendedPolicy)
    assert isinstance(PassivityPolicy.from_env(SoftPVTOLEnv(), loop="extended"), ExtendedPolicy)
    with pytest.raises(ValueError, match="not a passivity loop"):
        PassivityPolicy(env.config, loop="extended")
    with pytest.raises(ValueError, match="action_mode='actuators' only"):
        PassivityPolicy.from_env(SoftPVTOLEnv(action_mode="virtual"), loop="extended")


def test_policy_memory_resets_at_episode_start():
    env = SoftPVTOLEnv(action_mode="actuators", task="track_paper", tier="nominal")
    policy = PassivityPolicy.from_env(env, loop="extended")
    obs, _ = env.reset(seed=0)
    first, _ = policy.predict(obs, episode_start=True)
    policy.predict(obs)
    again, _ = policy.predict(obs, episode_start=True)
    assert np.array_equal(first, again) and first.dtype == np.float32 and first.shape == (4,)
    batch, _ = policy.predict(np.stack([obs, obs]), episode_start=True)  # a new batch size: fresh memory
    assert np.array_equal(batch[0], first) and np.array_equal(batch[1], first)
    with pytest.raises(ValueError, match="must be finite"):
        policy.predict(np.full(18, np.nan, dtype=np.float32))


@pytest.mark.slow  # 15 s of an episode (1,500 policy steps)
def test_policy_in_the_env_tracks_without_saturating():
    """track_paper nominal, actuators mode, default limits (benchmarks/extended_loop.py runs the whole
    episode: the committed figures are re-checked above)."""
    env = SoftPVTOLEnv(action_mode="actuators", task="track_paper", tier="nominal")
    policy = PassivityPolicy.from_env(env, loop="extended")
    obs, _ = env.reset(seed=0)
    errs, sat, start = [], 0, True
    for _ in range(1500):
        action, _ = policy.predict(obs, episode_start=start)
        start = False
        sat += int(np.any(np.abs(action) >= 1.0))
        obs, _, terminated, truncated, _ = env.step(action)
        assert not terminated
        errs.append(np.hypot(obs[0], obs[1]))
    assert sat == 0 and max(errs[-200:]) < 0.05, (sat, max(errs[-200:]))


@pytest.mark.parametrize("tier", ["nominal", "hard"])
def test_compiled_policy_is_the_numpy_reference(tier):
    """ExtendedPolicy.predict (one compiled pass, control.extended_kernels) against predict_reference (numpy,
    through ExtendedController): the same actions and extension along the vector env's episodes, with
    memories reset at random steps, a batch large enough to be split over threads,
    and a controller that holds the start's command."""
    from softpvtol_gym import SoftPVTOLVectorEnv

    n = 300
    env = SoftPVTOLVectorEnv(num_envs=n, action_mode="actuators", task="track_random", tier=tier)
    fast = PassivityPolicy.from_env(env, loop="extended")
    ref = PassivityPolicy.from_env(env, loop="extended")
    obs, _ = env.reset(seed=1)
    start, restarted, rng = np.ones(n, dtype=bool), 0, np.random.default_rng(0)
    for _ in range(150):
        a, _ = fast.predict(obs, episode_start=start)
        b, _ = ref.predict_reference(obs, episode_start=start)
        assert a.dtype == np.float32 and a.shape == (n, 4)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.controller.thrust_state, ref.controller.thrust_state, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(fast._hist_len, ref._hist_len)
        obs, _, terminated, truncated, _ = env.step(b)
        start = terminated | truncated | (rng.random(n) < 0.01)  # and memories forgotten mid-episode
        restarted += int(start.sum())
    assert restarted > 100
    one = SoftPVTOLEnv(action_mode="actuators", task="track_paper", tier=tier)
    for held in ("start", "midpoint"):
        fast, ref = (PassivityPolicy.from_env(one, loop="extended") for _ in range(2))
        for pol in (fast, ref):
            pol.controller.held_command = held
        o, _ = one.reset(seed=2)
        for k in range(20):
            a, _ = fast.predict(o, episode_start=k == 0)
            b, _ = ref.predict_reference(o, episode_start=k == 0)
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
            o = one.step(b)[0]


@pytest.mark.parametrize("held", ["midpoint", "start"])
def test_a_rows_action_does_not_depend_on_its_batch(held):
    """The midpoint predictions of a batch of 64 rows or more run as SIMD lane blocks (model.rk4_lanes), a smaller
    batch's lane by lane: every row's actions and extension equal those of the row alone (its own policy, a batch
    of one), bit for bit, along 70 envs' episodes (a full block and a partial one), one row's arms sent beyond the
    model's range at the midpoint (the start's command held) at one step."""
    from softpvtol_gym import SoftPVTOLVectorEnv

    n = 70
    env = SoftPVTOLVectorEnv(num_envs=n, action_mode="actuators", task="track_random", tier="wind")
    batch = PassivityPolicy.from_env(env, loop="extended")
    alone = [PassivityPolicy.from_env(env, loop="extended") for _ in range(n)]
    for pol in (batch, *alone):
        pol.controller.held_command = held
    obs, _ = env.reset(seed=4)
    start = np.ones(n, dtype=bool)
    for k in range(40):
        if k == 20:  # row 5: arms at 3 rad bending at 1000 rad/s, past pi at the midpoint
            obs[5, 5], obs[5, 10] = 3.0, 1000.0
        a, _ = batch.predict(obs, episode_start=start)
        for i, pol in enumerate(alone):
            b, _ = pol.predict(obs[i:i + 1], episode_start=start[i:i + 1])
            assert a[i].tobytes() == b[0].tobytes(), (k, i)
            assert batch.controller.thrust_state[i].tobytes() == pol.controller.thrust_state[0].tobytes()
        obs, _, terminated, truncated, _ = env.step(a)
        start = terminated | truncated
