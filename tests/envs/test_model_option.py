"""The env's ``model=`` argument and the "model_gap" tier: the plant integrates the chosen model
(consistent: rotor masses at the rotated tips, its own virtual-work input map) while the controllers
keep the paper's model. The reference is a plain RK4 of the public model functions (as in
test_env_hold.py), with ``model="consistent"``."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from softpvtol_gym import PassivityPolicy, SoftPVTOLEnv, SoftPVTOLVectorEnv
from softpvtol_gym.dynamics import forward_dynamics, generalized_forces, total_energy
from softpvtol_gym.envs.tiers import TIERS

TOL = dict(rtol=1e-12, atol=1e-12)


def rk4_held(q, v, force_at, params, dt, model):
    h = 0.5 * dt
    k1 = forward_dynamics(q, v, force_at(q), params, model=model)
    q2, v2 = q + h * v, v + h * k1
    k2 = forward_dynamics(q2, v2, force_at(q2), params, model=model)
    q3, v3 = q + h * v2, v + h * k2
    k3 = forward_dynamics(q3, v3, force_at(q3), params, model=model)
    q4, v4 = q + dt * v3, v + dt * k3
    k4 = forward_dynamics(q4, v4, force_at(q4), params, model=model)
    return q + dt / 6 * (v + 2 * v2 + 2 * v3 + v4), v + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


CASES = [
    dict(action_mode="actuators", tier="model_gap"),
    dict(action_mode="actuators", model="consistent", input_map="exact"),
    dict(action_mode="actuators", model="consistent", tier="mismatch"),
    dict(action_mode="virtual", tier="model_gap"),
    dict(action_mode="residual", tier="model_gap"),
    dict(action_mode="virtual", allocation="ideal", model="consistent", tier="wind"),
]


def make_env(frame_skip: int, **kw) -> SoftPVTOLEnv:
    """The env of a case; the residual mode with frame_skip=2 (0.02 s held) warns (on purpose: its base controller's arm
    loop diverges when held that long, test_control_loops.py) and the warning is checked here."""
    expect = kw.get("action_mode") == "residual" and frame_skip > 1
    with pytest.warns(UserWarning, match="arm loop diverges") if expect else contextlib.nullcontext():
        return SoftPVTOLEnv(task="track_random", frame_skip=frame_skip, **kw)


@pytest.mark.parametrize("frame_skip", [1, 2])
@pytest.mark.parametrize("kw", CASES, ids=lambda kw: "-".join(f"{v}" for v in kw.values()))
def test_consistent_plant_is_rk4_of_the_consistent_model(kw, frame_skip):
    """Whatever input map the controllers assume, the consistent plant applies its own ("exact");
    the ideal mode holds tau. Energy in info is the consistent model's."""
    env = make_env(frame_skip, **kw)
    assert env.config.plant_model == "consistent"
    env.reset(seed=3)
    sim = env.sim
    ideal = env.config.allocation == "ideal"
    rng = np.random.default_rng(0)
    steps = 0
    for _ in range(30):
        q, v = env.state
        if np.max(np.abs(q[3:])) > 2.5:
            break
        p = env.plant_params
        wind = np.r_[sim.wind[0], 0.0, 0.0, 0.0]
        _, _, _, _, info = env.step(rng.uniform(-0.3, 0.3, env.action_space.shape))
        applied = sim.applied[0].copy()

        def force(qs, applied=applied, wind=wind, p=p):
            if ideal:
                return applied + wind
            return generalized_forces(qs, applied[:4], p, model="consistent") + wind

        for _ in range(frame_skip):
            q, v = rk4_held(q, v, force, p, 0.01, "consistent")
        np.testing.assert_allclose(env.state[0], q, **TOL)
        np.testing.assert_allclose(env.state[1], v, **TOL)
        assert info["total_energy"] == pytest.approx(total_energy(q, v, p, model="consistent"), rel=1e-12, abs=1e-9)
        steps += 1
    assert steps >= 10


def test_model_gap_tier_is_nominal_with_a_consistent_plant():
    """Same episode as the nominal tier (same start, no disturbance); the trajectories part because the
    plant differs, and the default env and model="paper" are the same env."""
    runs = {}
    for kw in (dict(tier="nominal"), dict(tier="nominal", model="paper"), dict(tier="model_gap"),
               dict(tier="nominal", model="consistent")):
        env = SoftPVTOLEnv(task="track_paper", **kw)
        policy = PassivityPolicy.from_env(env)
        obs, _ = env.reset(seed=0)
        q0 = env.state[0]
        for _ in range(200):
            obs, *_ = env.step(policy.predict(obs)[0])
        runs[tuple(kw.items())] = (q0, env.state[0])
    (a0, a1), (b0, b1), (c0, c1), (d0, d1) = runs.values()
    np.testing.assert_array_equal(a0, c0)
    np.testing.assert_array_equal(a1, b1)  # model="paper" is the default
    np.testing.assert_array_equal(c1, d1)  # the tier = model="consistent" on the nominal tier
    assert np.abs(a1 - c1).max() > 1e-4


def test_vector_env_matches_single_env_under_the_model_gap():
    n = 3
    venv = SoftPVTOLVectorEnv(num_envs=n, tier="model_gap", task="hover", action_mode="residual")
    envs = [SoftPVTOLEnv(tier="model_gap", task="hover", action_mode="residual") for _ in range(n)]
    obs_v, _ = venv.reset(seed=[10, 11, 12])
    for i, e in enumerate(envs):
        o, _ = e.reset(seed=10 + i)
        np.testing.assert_array_equal(o, obs_v[i])
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(-1, 1, (n, 5)).astype(np.float32)
        obs_v, r_v, *_ = venv.step(a)
        for i, e in enumerate(envs):
            o, r, *_ = e.step(a[i])
            np.testing.assert_array_equal(o, obs_v[i])
            assert r == r_v[i]


def test_model_argument_validation():
    assert "model_gap" in TIERS
    assert SoftPVTOLEnv().config.plant_model == "paper"
    assert SoftPVTOLEnv(tier="model_gap").config.plant_model == "consistent"
    assert SoftPVTOLEnv(tier="model_gap", model="consistent").config.plant_model == "consistent"
    for bad in ("Consistent", "exact", "", 1):
        with pytest.raises(ValueError, match=r"model must be one of \[None, 'paper', 'consistent'\]"):
            SoftPVTOLEnv(model=bad)
    with pytest.raises(ValueError, match="tier='model_gap' integrates the consistent model.*model='paper'"):
        SoftPVTOLEnv(tier="model_gap", model="paper")


def test_committed_passivity_metrics_model_gap_column_is_reproduced():
    """The model_gap column of results/passivity_metrics.json (python
    baselines/passivity_metrics.py) is what the script computes now; the other columns are unchanged
    by the consistent model (the default plant is bit-identical)."""
    import json
    from pathlib import Path

    from softpvtol_gym.baselines.commands.passivity_metrics import run_cell

    data = json.loads((Path(__file__).resolve().parents[2] / "results/passivity_metrics.json").read_text())
    for task in ("hover", "track_paper"):
        cell = run_cell(task, "model_gap", data["cells"][f"{task}/model_gap"]["episodes"], data["seed"])
        assert cell == data["cells"][f"{task}/model_gap"], (task, cell)
    nominal = run_cell("hover", "nominal", 10, data["seed"])
    assert nominal == data["cells"]["hover/nominal"]


def test_pickled_env_keeps_its_plant_and_refuses_old_constants():
    """The constants (with the plant-model flag) are pickled with their layout's signature: a model_gap
    env round-trips; state saved under the previous constants layout (no flag) is refused, not misread."""
    import pickle

    env = SoftPVTOLEnv(tier="model_gap", task="hover")
    env.reset(seed=4)
    a = np.zeros(4, dtype=np.float32)
    env.step(a)
    clone = pickle.loads(pickle.dumps(env))
    for e in (env, clone):
        e.step(a)
    np.testing.assert_array_equal(env.state[0], clone.state[0])
    state = env.sim.__getstate__()
    state["layouts"] = state["layouts"][:2]
    with pytest.raises(ValueError, match="saved state was packed with layout"):
        type(env.sim).__new__(type(env.sim)).__setstate__(state)
