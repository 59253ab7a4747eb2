"""The env's compiled step against the plain-numpy reference of tests/envs/reference_env.py.

Every action mode (actuators; virtual with allocation exact / paper / ideal; residual with allocation
exact / paper and residual_space virtual / actuators) x tier (nominal, mismatch, wind, noisy, hard) x
task (hover, setpoint, track_paper, track_random), over >= 200 steps with resets (short episodes, so
several episodes end by truncation, and a reset with a new seed mid-way), single env and vector env.

Tolerance: TOL = 1e-12, mixed absolute/relative as numpy's allclose: |env - ref| <= TOL + TOL |ref|
(absolute below magnitude 1, relative above), on the true state (q, qdot), the measured state, the
reward, every reward term and the float diagnostics of the info; the applied command (actuators,
or tau in ideal mode) to TOL x its full scale (T_max, tau_max; ideal: the virtual scales): the residual
controller's arm torques amplify input differences of 1e-16 by ~1e3-1e4 (allocation sensitivity times
the arm gains K Lambda), measured up to 5e-12 N m of the 9.8 N m range. Termination,
truncation, the termination reason and the boolean flags must be equal. The observation is float32:
|obs - ref| <= half a float32 ulp of ref + TOL (1 + |ref|) (the rounding of the float64 value).

Residual mode with allocation="paper": the paper allocation's Newton stops at a residual of 1e-10, so a
1e-16 change of its input (the measured state the env and the reference compute in a different order)
can change the iteration count and make the arm torques jump by ~1e-9 (measured: up to 3e-9 N m, a
state difference of ~1e-11 after 0.2 s). In that case only, the reference's base controller is fed the
env's measured state (after checking that it equals the reference's own to TOL at every step); all
other pieces (noise, lag, saturation, physics, observation, reward) remain the reference's own.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv, dynamics
from tests.envs.reference_env import Model, ReferenceEnv, curvature_functions, episode_from_sim

TOL = 1e-12
TIERS = ("nominal", "mismatch", "wind", "noisy", "hard")
TASKS = ("hover", "setpoint", "track_paper", "track_random")
#: action-mode variants: name -> env kwargs
MODES = {
    "actuators": dict(action_mode="actuators"),
    "virtual-exact": dict(action_mode="virtual", allocation="exact"),
    "virtual-paper": dict(action_mode="virtual", allocation="paper"),
    "virtual-ideal": dict(action_mode="virtual", allocation="ideal"),
    # the residual modes run base loops without feedforward here: the default "bounded" loop's
    # backward differences divide by dt^2 = 1e-4, so last-bit differences of the arm references
    # reach ~1e-11 N m in the arm torques; it is checked against a per-piece reference in
    # tests/benchmarks/test_benchmarks.py (test_residual_env_and_policy_run_the_fused_controller) instead
    "residual-exact": dict(action_mode="residual", allocation="exact", controller_loop="exact"),
    "residual-paper": dict(action_mode="residual", allocation="paper"),
    "residual-actuators": dict(action_mode="residual", residual_space="actuators", controller_loop="exact"),
}
FLOAT_INFO = ("total_energy", "storage_function", "curvature_violation", "allocation_residual", "time")
BOOL_INFO = ("thrust_saturated", "arm_torque_saturated", "action_clipped")


def _kwargs(mode: str, tier: str, task: str, i: int) -> dict:
    """Env kwargs of grid case i: the input map alternates; one tier per mode runs frame_skip 2 (not in
    residual mode: its base controller's arm loop is unstable under a 0.02 s hold (docs/control.md), so
    any difference, 1e-16 included, grows exponentially and no reference can follow it to 1e-12)."""
    fs = 2 if TIERS.index(tier) == list(MODES).index(mode) % 5 and MODES[mode]["action_mode"] != "residual" else 1
    return dict(MODES[mode], tier=tier, task=task, max_episode_seconds=0.6 if i % 2 else 0.45,
                input_map=("paper", "exact")[i % 2], frame_skip=fs)


def _action_bias(env_kwargs: dict, dim: int) -> np.ndarray:
    """Action near hover: actuators mode T = T_max (u + 1)/2 = hover thrust at u = -1/3 (T_max = 3 T_h),
    arm torques at 1/4 (the arm gravity load g m l / 2 = tau_max / 4); 0 in the other modes."""
    b = np.zeros(dim)
    if env_kwargs.get("action_mode", "actuators") == "actuators":
        b[:] = (-1 / 3, -1 / 3, 0.25, 0.25)
    return b


# ---------------------------------------------------------------------------------- comparison
def _close(env_value, ref_value, what: str) -> None:
    np.testing.assert_allclose(env_value, ref_value, rtol=TOL, atol=TOL, err_msg=what)


def _close_obs(obs32, ref64, what: str) -> None:
    obs32 = np.asarray(obs32, dtype=np.float32)
    assert obs32.dtype == np.float32 and obs32.shape == (18,)
    ref64 = np.asarray(ref64, dtype=np.float64)
    half_ulp = 0.5 * np.spacing(np.abs(ref64).astype(np.float32)).astype(np.float64)
    err = np.abs(obs32.astype(np.float64) - ref64)
    bad = err > half_ulp + TOL * (1.0 + np.abs(ref64))
    assert not bad.any(), f"{what}: observation entries {np.flatnonzero(bad)} differ: {obs32[bad]} vs {ref64[bad]}"


def _check_sim_row(sim, i: int, ref: ReferenceEnv, what: str) -> None:
    """True and measured state of sub-env i against the reference."""
    _close(sim.q[i], ref.q, f"{what}: q")
    _close(sim.qd[i], ref.qd, f"{what}: qdot")
    _close(sim.qm[i], ref.qm, f"{what}: measured q")
    _close(sim.qdm[i], ref.qdm, f"{what}: measured qdot")


def _check_step(what, obs, reward, terminated, truncated, info, sim, i, ref, res) -> None:
    _close_obs(obs, res.obs, what)
    _close(reward, res.reward, f"{what}: reward")
    for name, value in res.terms.items():
        _close(info["reward_terms"][name], value, f"{what}: reward term {name}")
    assert bool(terminated) == res.terminated, f"{what}: terminated {terminated} vs {res.terminated} ({res.reason})"
    assert bool(truncated) == res.truncated, f"{what}: truncated {truncated} vs {res.truncated}"
    assert info["termination_reason"] == res.reason, what
    for name in FLOAT_INFO:
        _close(info[name], res.info[name], f"{what}: info {name}")
    for name in BOOL_INFO:
        assert bool(info[name]) == res.info[name], f"{what}: info {name}"
    _check_sim_row(sim, i, ref, what)
    n = ref.applied.shape[0]
    scale = ref.v_scale if ref.ideal else np.array([ref.tmax, ref.tmax, ref.taumax, ref.taumax])
    err = np.abs(sim.applied[i, :n] - ref.applied)
    assert (err <= TOL * scale).all(), f"{what}: applied command {sim.applied[i, :n]} vs {ref.applied}"


def _vector_info(info: dict, i: int) -> dict:
    out = {k: (v[i] if isinstance(v, np.ndarray) else None) for k, v in info.items() if not k.startswith("_")}
    out["reward_terms"] = {k: v[i] for k, v in info["reward_terms"].items()}
    return out


def _measured(sim, i: int, ref: ReferenceEnv, mode: str, what: str):
    """The env's measured state as the residual-paper controller's input (see the module docstring)."""
    if mode != "residual-paper":
        return None
    _close(sim.qm[i], ref.qm, f"{what}: measured q before the step")
    _close(sim.qdm[i], ref.qdm, f"{what}: measured qdot before the step")
    return sim.qm[i].copy(), sim.qdm[i].copy()


def _actions(rng, bias, dim: int, k: int, n: int | None = None) -> np.ndarray:
    """Modest random actions around the bias; step 7 of every 30 has entries out of [-1, 1] (clipped)."""
    shape = (dim,) if n is None else (n, dim)
    a = bias + rng.uniform(-0.25, 0.25, shape)
    if k % 30 == 7:
        a[..., 0], a[..., -1] = 1.5, -1.0 - rng.uniform(0.1, 2.0)
    return a.astype(np.float32)


# ------------------------------------------------------------------------------------ single env
def run_single(mode: str, env_kwargs: dict, steps: int = 140, seed: int = 0, actions=None) -> dict:
    """Step the env and the reference side by side; returns counts of what happened."""
    env = SoftPVTOLEnv(**env_kwargs)
    ref = ReferenceEnv(env.config)
    obs, info = env.reset(seed=seed)
    _close_obs(obs, ref.start_from_sim(env.sim, 0), "reset")
    _check_sim_row(env.sim, 0, ref, "reset")
    rng = np.random.default_rng(seed + 1)
    dim = env.action_space.shape[0]
    bias = _action_bias(env_kwargs, dim)
    seen = {"episodes": 1, "terminated": 0, "truncated": 0, "clipped": 0, "reasons": set()}
    for k in range(steps):
        what = f"{mode} {env_kwargs} step {k}"
        if k == steps // 2:  # a reset with a new seed mid-way
            obs, _ = env.reset(seed=seed + 1000)
            _close_obs(obs, ref.start_from_sim(env.sim, 0), f"{what}: reset(seed)")
            seen["episodes"] += 1
        a = _actions(rng, bias, dim, k) if actions is None else actions(k, dim)
        measured = _measured(env.sim, 0, ref, mode, what)
        obs, reward, terminated, truncated, info = env.step(a)
        res = ref.step(a, measured)
        _check_step(what, obs, reward, terminated, truncated, info, env.sim, 0, ref, res)
        seen["clipped"] += info["action_clipped"]
        if terminated or truncated:
            seen["terminated" if terminated else "truncated"] += 1
            seen["reasons"].add(info["termination_reason"])
            obs, _ = env.reset()
            _close_obs(obs, ref.start_from_sim(env.sim, 0), f"{what}: reset")
            _check_sim_row(env.sim, 0, ref, f"{what}: reset")
            seen["episodes"] += 1
    return seen


def _grid():
    """Every mode x tier x task; the fast set covers each (mode, tier) pair once and each task in each
    mode (the task cycles with the tier); the rest is marked slow."""
    cases = []
    for i, (mode, tier, task) in enumerate(itertools.product(MODES, TIERS, TASKS)):
        m, j, k = list(MODES).index(mode), TIERS.index(tier), TASKS.index(task)
        fast = k == (m + j) % 4
        marks = () if fast else (pytest.mark.slow,)
        cases.append(pytest.param(mode, tier, task, i, marks=marks, id=f"{mode}-{tier}-{task}"))
    return cases


@pytest.mark.parametrize("mode,tier,task,i", _grid())
def test_single_env_matches_reference(mode, tier, task, i):
    seen = run_single(mode, _kwargs(mode, tier, task, i), seed=i)
    assert seen["episodes"] >= 4  # resets happened (truncation at 0.45/0.6 s and the mid-way reseed)
    assert seen["clipped"] >= 4  # clipped actions were exercised


@pytest.mark.parametrize("mode", ["actuators", "virtual-ideal"])
@pytest.mark.parametrize("reason,tier", [("ground", "nominal"), ("curvature_limit", "hard")])
def test_terminating_episodes_match_reference(mode, reason, tier):
    """Actions that end every episode: no thrust (actuators) / tau_z = -M g (ideal) (ground), or full arm
    torque (curvature limit); the reference must agree on the step and the reason of every termination."""
    kw = dict(MODES[mode], tier=tier, task="hover")

    def actions(k, dim):
        a = np.zeros(dim, dtype=np.float32)
        if mode == "actuators":
            a[:2] = -1.0 if reason == "ground" else -1 / 3
        elif reason == "ground":
            a[1] = -1.0
        if reason == "curvature_limit":
            a[-2:] = 1.0
        return a

    seen = run_single(mode, kw, steps=220, seed=3, actions=actions)
    assert seen["terminated"] >= 2 and seen["reasons"] == {reason}, seen


# ------------------------------------------------------------------------------------ vector env
def run_vector(mode: str, env_kwargs: dict, num_envs: int = 3, steps: int = 200, seed: int = 0) -> dict:
    venv = SoftPVTOLVectorEnv(num_envs=num_envs, **env_kwargs)
    sim = venv.sim
    refs = [ReferenceEnv(venv.config) for _ in range(num_envs)]
    obs, _ = venv.reset(seed=seed)
    for i, ref in enumerate(refs):
        _close_obs(obs[i], ref.start_from_sim(sim, i), f"reset sub-env {i}")
    rng = np.random.default_rng(seed + 1)
    dim = venv.single_action_space.shape[0]
    bias = _action_bias(env_kwargs, dim)
    pending = np.zeros(num_envs, dtype=bool)  # NextStep autoreset: these sub-envs reset at this step
    seen = {"autoresets": 0}
    for k in range(steps):
        if k == steps // 2:
            obs, _ = venv.reset(seed=seed + 1000)
            for i, ref in enumerate(refs):
                _close_obs(obs[i], ref.start_from_sim(sim, i), f"step {k}: reset(seed) sub-env {i}")
            pending[:] = False
        a = _actions(rng, bias, dim, k, num_envs)
        measured = [_measured(sim, i, refs[i], mode, f"step {k} sub-env {i}") for i in range(num_envs)]
        obs, rewards, terminated, truncated, info = venv.step(a)
        for i, ref in enumerate(refs):
            what = f"vector {mode} {env_kwargs} step {k} sub-env {i}"
            if pending[i]:  # autoreset: a new episode, reward 0, not done
                assert rewards[i] == 0.0 and not terminated[i] and not truncated[i], what
                _close_obs(obs[i], ref.start_from_sim(sim, i), f"{what}: autoreset")
                _check_sim_row(sim, i, ref, f"{what}: autoreset")
                seen["autoresets"] += 1
                continue
            res = ref.step(a[i], measured[i])
            _check_step(what, obs[i], rewards[i], terminated[i], truncated[i], _vector_info(info, i), sim, i, ref,
                        res)
        pending = terminated | truncated
    return seen


@pytest.mark.parametrize(
    "mode,tier,task",
    [
        ("actuators", "hard", "track_random"),
        ("virtual-exact", "noisy", "hover"),
        ("residual-exact", "wind", "track_paper"),
        pytest.param("virtual-paper", "mismatch", "setpoint", marks=pytest.mark.slow),
        pytest.param("virtual-ideal", "hard", "track_paper", marks=pytest.mark.slow),
        pytest.param("residual-paper", "hard", "hover", marks=pytest.mark.slow),
        pytest.param("residual-actuators", "hard", "track_random", marks=pytest.mark.slow),
    ],
)
def test_vector_env_matches_reference(mode, tier, task):
    kw = dict(MODES[mode], tier=tier, task=task, max_episode_seconds=0.5)
    seen = run_vector(mode, kw, num_envs=3, steps=200, seed=11)
    assert seen["autoresets"] >= 6


# ------------------------------------------------------------------------- the reference itself
def test_reference_model_matches_public_dynamics():
    """The reference's own D, C, g, B(q) a and energy (docs/model.md) against softpvtol_gym.dynamics,
    including curvatures near 0 (series branch), around 1 (branch switch) and up to 2 pi."""
    rng = np.random.default_rng(5)
    p = SoftPVTOLParams(m_l=1.3, l_r=0.6, epsilon=0.05, I_r=0.2)
    model = Model(p)
    curv = np.concatenate([rng.uniform(-6.2, 6.2, 60), [0.0, 1e-9, -1e-5, 0.999999, 1.0, -1.000001, np.pi]])
    for j, ql in enumerate(curv):
        q = np.array([rng.normal(), rng.normal() + 2, rng.uniform(-3, 3), ql, curv[::-1][j]])
        qd, a = rng.normal(size=5) * 3, rng.uniform(0, 60, 4)
        D, C, g = model.terms(q, qd)
        _close(D, dynamics.mass_matrix(q, p), "D")
        np.testing.assert_allclose(C, dynamics.coriolis_matrix(q, qd, p), rtol=TOL, atol=10 * TOL)
        _close(g, dynamics.gravity_vector(q, p), "g")
        for imap in ("paper", "exact"):
            _close(model.generalized_forces(q, a, imap), dynamics.generalized_forces(q, a, p, imap), imap)
        _close(model.energy(q, qd), dynamics.total_energy(q, qd, p), "energy")
    # the series branch and the closed form agree where they meet
    for f_lo, f_hi in zip(curvature_functions(1.0 - 1e-12), curvature_functions(1.0)):
        assert abs(f_lo - f_hi) < 1e-11


def test_config_scales_follow_the_docs():
    """The action scales the reference derives from docs/env.md equal the env's own (EnvConfig)."""
    for kw in (dict(action_mode="residual"), dict(action_mode="virtual", actuator_limits=(50.0, 3.0))):
        env = SoftPVTOLEnv(**kw)
        ref, cfg = ReferenceEnv(env.config), env.config
        assert ref.tmax == pytest.approx(cfg.thrust_max, rel=1e-15)
        assert ref.taumax == pytest.approx(cfg.arm_torque_max, rel=1e-15)
        _close(ref.v_scale, cfg.virtual_scale, "virtual scale")
        _close(ref.v_offset, cfg.virtual_offset, "virtual offset")
        _close(ref.res_tau_scale, cfg.residual_tau_scale, "residual tau scale")
        _close(ref.res_act_scale, cfg.residual_actuator_scale, "residual actuator scale")
        assert ref.dt == cfg.dt
    assert ReferenceEnv(SoftPVTOLEnv().config).tmax == pytest.approx(102.9, rel=1e-12)
    assert ReferenceEnv(SoftPVTOLEnv().config).taumax == pytest.approx(9.8, rel=1e-12)


def test_track_random_parameters_in_documented_ranges():
    """The per-episode track_random parameters the reference reads lie in the documented ranges and
    give the documented start (the reference at t = 0 +- half the hover perturbation)."""
    venv = SoftPVTOLVectorEnv(num_envs=64, task="track_random")
    venv.reset(seed=2)
    for i in range(64):
        ep = episode_from_sim(venv.sim, i, "track_random")
        assert ep.ref["z0"] == 3.0
        for axis, amax in (("x", 1.0), ("z", 0.5)):
            A, w, ph = ep.ref[axis]
            assert ((A >= 0) & (A <= amax)).all() and ((w >= 0.2) & (w <= 0.8)).all()
            assert ((ph >= 0) & (ph < 2 * np.pi)).all()
        r0 = ReferenceEnv(venv.config)
        r0.start(ep)
        dq = ep.q0 - r0.ref[0]
        assert (np.abs(dq) <= 0.5 * np.array([1.0, 1.0, 0.3, 0.3, 0.3]) + 1e-12).all()
        assert (np.abs(ep.qd0 - r0.ref[1]) <= 0.5 * np.array([0.5, 0.5, 0.2, 0.2, 0.2]) + 1e-12).all()
