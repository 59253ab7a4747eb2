"""Statistical tests of the tiers (docs/env.md "Tiers"): wind OU std and correlation time, observation
noise std per entry, actuator lag time constant, mismatch ranges, tier_options overrides.

Tolerances come from the sample sizes: every statistic is compared with its expected value within
Z = 5 standard errors (two-sided false-alarm probability 6e-7 per comparison for a normal estimate;
the seeds are fixed anyway, so the tests are deterministic), and each test also checks that the standard
error is small enough for the comparison to mean something. How each standard error is obtained is
said where it is computed: for iid samples from the textbook formulas (std of a variance estimate
sigma^2 sqrt(2/n), of a mean sigma/sqrt(n), of a proportion sqrt(p(1-p)/n), of a correlation 1/sqrt(n));
for the time-correlated wind from the spread of per-env estimates across independent sub-envs (each
sub-env has its own key, so its wind series is an independent replicate).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from softpvtol_gym import SoftPVTOLEnv, SoftPVTOLParams, SoftPVTOLVectorEnv

Z = 5.0
HOVER_ACTION = np.array([-1 / 3, -1 / 3, 0.25, 0.25], dtype=np.float32)  # T = T_h, arm torque = gravity load
MISMATCH_FIELDS = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")
FIELDS = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r", "g", "epsilon")


# -------------------------------------------------------------------------------------- wind
def wind_series(num_envs: int, steps: int, seed: int, **kw) -> np.ndarray:
    """Wind force (steps + 1, num_envs, 2) [N] of a vector-env rollout (index 0: the reset's draw).

    No autoreset (a reset would redraw the wind): the wind depends only on the episode key and the
    step counter, not on the state, so sub-envs that terminate keep a valid wind series."""
    venv = SoftPVTOLVectorEnv(num_envs=num_envs, autoreset_mode="Disabled", max_episode_seconds=1e4, **kw)
    venv.reset(seed=seed)
    W = np.empty((steps + 1, num_envs, 2))
    W[0] = venv.sim.wind
    a = np.tile(HOVER_ACTION, (num_envs, 1))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        # stepping the sub-envs that have terminated is the point (their wind series goes on): the env's
        # warning about it (tested in test_bad_input_env.py) would repeat at every step with another list
        warnings.filterwarnings("ignore", message=r".*You are calling 'step\(\)' on sub-envs .* already returned",
                                category=UserWarning)
        for k in range(steps):
            venv.step(a)
            W[k + 1] = venv.sim.wind
    return W


def _ratio_estimate(num: np.ndarray, den: np.ndarray) -> tuple[float, float]:
    """Ratio of means mean(num)/mean(den) over independent replicates and its standard error by the
    delta method: Var(R) ~ Var(num_i - R den_i) / (n mean(den)^2)."""
    r = num.mean() / den.mean()
    se = (num - r * den).std(ddof=1) / (math.sqrt(num.size) * den.mean())
    return float(r), float(se)


def check_wind(W: np.ndarray, std: float, tau: float, dt: float, lags=(10, 50, 100)) -> None:
    N = W.shape[1]
    # stationary variance: per sub-env mean of w^2 over time and both axes (a replicate each); the
    # standard error is the spread of the replicates / sqrt(N)
    per_env = (W**2).mean(axis=(0, 2))
    var, se = per_env.mean(), per_env.std(ddof=1) / math.sqrt(N)
    assert se < 0.02 * std**2, f"too few samples: SE {se}"
    assert abs(var - std**2) < Z * se, f"stationary variance {var:.4f} vs {std**2} (SE {se:.4f})"
    # stationary from the start: the reset's draws alone (2N iid normals; SE of a variance
    # sigma^2 sqrt(2 / n)) and the last step's
    for k in (0, W.shape[0] - 1):
        v = (W[k] ** 2).mean()
        assert abs(v - std**2) < Z * std**2 * math.sqrt(2 / (2 * N)), f"variance at step {k}: {v}"
    # correlation time: rho(k) = C(k) / C(0) = exp(-k dt / tau); per-env lagged products over the same
    # time range as the variance they are divided by (ratio of means, delta-method SE over sub-envs)
    T = W.shape[0]
    for k in lags:
        num = (W[k:] * W[: T - k]).mean(axis=(0, 2))
        den = 0.5 * ((W[k:] ** 2).mean(axis=(0, 2)) + (W[: T - k] ** 2).mean(axis=(0, 2)))
        rho, se_rho = _ratio_estimate(num, den)
        expected = math.exp(-k * dt / tau)
        assert se_rho < 0.02, f"too few samples at lag {k}: SE {se_rho}"
        assert abs(rho - expected) < Z * se_rho, f"rho({k}) = {rho:.4f} vs {expected:.4f} (SE {se_rho:.4f})"
        # the implied correlation time and its SE (delta method: d tau / d rho = k dt / (rho ln(rho)^2))
        tau_hat = -k * dt / math.log(rho)
        se_tau = k * dt / (rho * math.log(rho) ** 2) * se_rho
        assert abs(tau_hat - tau) < Z * se_tau, f"tau from lag {k}: {tau_hat:.4f} vs {tau} (SE {se_tau:.4f})"
    # x and z are independent: correlation of wx and wz at equal times, SE over sub-envs
    r, se_r = _ratio_estimate((W[..., 0] * W[..., 1]).mean(axis=0), (W**2).mean(axis=(0, 2)))
    assert abs(r) < Z * se_r, f"corr(w_x, w_z) = {r}"


def test_wind_tier_ou_std_3_newton_correlation_time_1_s():
    W = wind_series(num_envs=2048, steps=400, seed=0, tier="wind")
    check_wind(W, std=3.0, tau=1.0, dt=0.01)


@pytest.mark.parametrize(
    "options,std,tau,frame_skip",
    [({"wind_std": 1.0}, 1.0, 1.0, 1), ({"wind_correlation_time": 0.5}, 3.0, 0.5, 1), ({"wind_std": 2.0}, 2.0, 1.0, 2)],
)
def test_wind_tier_options(options, std, tau, frame_skip):
    """tier_options switch the wind on in the nominal tier with the given values (frame_skip 2: the
    wind is held over the 0.02 s control step and its correlation time is still in seconds)."""
    W = wind_series(num_envs=1024, steps=300, seed=1, tier="nominal", tier_options=options, frame_skip=frame_skip)
    check_wind(W, std=std, tau=tau, dt=0.01 * frame_skip, lags=(10, 50))


@pytest.mark.parametrize("tier", ["nominal", "mismatch", "noisy"])
def test_no_wind_outside_wind_tiers(tier):
    W = wind_series(num_envs=8, steps=20, seed=2, tier=tier)
    assert (W == 0.0).all()


# ------------------------------------------------------------------------------ observation noise
def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def noise_samples(tier: str, steps: int = 60, num_envs: int = 1024, seed: int = 3, **kw) -> np.ndarray:
    """obs - the noise-free observation of the true state, entries (0, 1, 2, 5, 6, 7..11):
    (steps + 1) * num_envs samples each."""
    venv = SoftPVTOLVectorEnv(num_envs=num_envs, tier=tier, task="hover", max_episode_seconds=1e4,
                              autoreset_mode="Disabled", **kw)
    obs, _ = venv.reset(seed=seed)
    sim = venv.sim
    a = np.tile(HOVER_ACTION, (num_envs, 1))
    out = []
    for k in range(steps + 1):
        if k:
            obs, *_ = venv.step(a)
        q, qd, qr = sim.q, sim.qd, sim.qr
        true = np.concatenate([q[:, 0:2] - qr[:, 0:2], _wrap(q[:, 2:3] - qr[:, 2:3]), q[:, 3:5], qd], axis=1)
        o = obs.astype(np.float64)[:, [0, 1, 2, 5, 6, 7, 8, 9, 10, 11]]
        d = o - true
        d[:, 2] = _wrap(d[:, 2])
        out.append(d)
    return np.stack(out)  # (steps + 1, num_envs, 10)


NOISE_STD = np.array([0.02, 0.02, 0.01, 0.02, 0.02, 0.05, 0.05, 0.02, 0.05, 0.05])


@pytest.mark.parametrize("tier,scale,kw", [("noisy", 1.0, {}), ("hard", 1.0, {}),
                                            ("nominal", 2.0, {"tier_options": {"obs_noise_scale": 2.0}})])
def test_observation_noise_std_per_entry(tier, scale, kw):
    """Per entry of (x, z, theta, q_l, q_r, xdot, zdot, thetadot, q_l dot, q_r dot): the noise (obs -
    the observation of the true state) has mean 0 and std scale x the documented one, is Gaussian,
    independent across entries and over time. n iid samples per entry (the noise of every (env, step,
    entry) is its own counter-based normal): SE of the std sigma / sqrt(2 n), of the mean sigma / sqrt(n),
    of a correlation 1 / sqrt(n), of the fraction inside 1 sigma sqrt(p (1 - p) / n)."""
    D = noise_samples(tier, **kw)
    X = D.reshape(-1, 10)
    n = X.shape[0]
    sigma = scale * NOISE_STD
    std = X.std(axis=0)
    assert (np.abs(std - sigma) < Z * sigma / math.sqrt(2 * n)).all(), f"std {std} vs {sigma}"
    assert (np.abs(X.mean(axis=0)) < Z * sigma / math.sqrt(n)).all(), X.mean(axis=0)
    zs = X / sigma
    p = math.erf(1 / math.sqrt(2))
    inside = (np.abs(zs) < 1).mean(axis=0)
    assert (np.abs(inside - p) < Z * math.sqrt(p * (1 - p) / n)).all(), inside
    R = np.corrcoef(zs.T)
    assert (np.abs(R - np.eye(10)) < Z / math.sqrt(n)).all(), "noise correlated across entries"
    lag1 = (zs.reshape(D.shape)[1:] * zs.reshape(D.shape)[:-1]).reshape(-1, 10).mean(axis=0)
    assert (np.abs(lag1) < Z / math.sqrt(n)).all(), f"noise correlated over time: {lag1}"


@pytest.mark.parametrize("tier", ["nominal", "mismatch", "wind"])
def test_no_observation_noise_outside_noisy_tiers(tier):
    D = noise_samples(tier, steps=10, num_envs=8)
    # float32 rounding of the observation only
    assert np.abs(D).max() < 1e-5
    env = SoftPVTOLEnv(tier=tier)
    env.reset(seed=0)
    env.step(HOVER_ACTION)
    assert (env.sim.qm[0] == env.sim.q[0]).all() and (env.sim.qdm[0] == env.sim.qd[0]).all()


# ------------------------------------------------------------------------------------ actuator lag
def step_response(tier: str, tau_expected: float, frame_skip: int = 1, action_mode: str = "actuators",
                  **kw) -> None:
    """Command A at the first step, B from then on: the applied command starts at A (the lag starts at
    the first command) and approaches B as B + (A - B) exp(-t / tau). The time constant is estimated
    by a least-squares fit of log((applied - B) / (A - B)) against t; deterministic (no noise enters
    the applied command), so the tolerance is floating-point: 1e-9 relative."""
    env = SoftPVTOLEnv(tier=tier, action_mode=action_mode, frame_skip=frame_skip, max_episode_seconds=10.0, **kw)
    env.reset(seed=4)
    dt = 0.01 * frame_skip
    if action_mode == "actuators":
        A, B = np.array([-0.6, -0.1, 0.1, 0.5]), np.array([0.2, -0.5, 0.4, -0.2])
        tmax, taumax = env.config.thrust_max, env.config.arm_torque_max
        phys = lambda u: np.array([tmax * (u[0] + 1) / 2, tmax * (u[1] + 1) / 2, taumax * u[2], taumax * u[3]])  # noqa: E731
    else:  # ideal: tau = offset + scale u, lagged in all five entries
        A, B = np.array([0.1, 0.05, -0.2, 0.3, -0.1]), np.array([-0.1, 0.0, 0.2, -0.3, 0.2])
        phys = lambda u: env.config.virtual_offset + env.config.virtual_scale * u  # noqa: E731
    pa, pb = phys(A), phys(B)
    env.step(A.astype(np.float32))
    applied = [env.sim.applied[0, : pa.size].copy()]
    np.testing.assert_allclose(applied[0], pa, rtol=1e-6)  # float32 action: 1e-7 relative
    for _ in range(12):
        env.step(B.astype(np.float32))
        applied.append(env.sim.applied[0, : pa.size].copy())
    applied = np.array(applied)
    frac = (applied - pb) / (pa - pb)  # exp(-k dt / tau), k = 0, 1, ...
    t = dt * np.arange(len(frac))
    for j in range(pa.size):
        slope = np.polyfit(t, np.log(frac[:, j]), 1)[0]
        assert -1 / slope == pytest.approx(tau_expected, rel=1e-5)  # float32 actions: ~1e-7 in frac
    # after one time constant, 1 - 1/e of the step is done (t = tau is a whole number of steps here)
    k = round(tau_expected / dt)
    if abs(k * dt - tau_expected) < 1e-12:
        np.testing.assert_allclose(1 - frac[k], 1 - math.exp(-1), rtol=1e-5)


def test_lag_time_constant_noisy_tier():
    step_response("noisy", 0.05)


@pytest.mark.parametrize("frame_skip", [1, 2])
def test_lag_time_constant_option(frame_skip):
    step_response("nominal", 0.1, frame_skip=frame_skip, tier_options={"actuator_time_constant": 0.1})


def test_lag_in_ideal_mode_covers_tau():
    step_response("hard", 0.05, action_mode="virtual", allocation="ideal")


@pytest.mark.parametrize("tier", ["nominal", "mismatch", "wind"])
def test_no_lag_outside_noisy_tiers(tier):
    env = SoftPVTOLEnv(tier=tier)
    env.reset(seed=0)
    for u in (np.array([-0.6, -0.1, 0.1, 0.5]), np.array([0.2, -0.5, 0.4, -0.2])):
        env.step(u.astype(np.float32))
        tmax, taumax = env.config.thrust_max, env.config.arm_torque_max
        expected = [tmax * (u[0] + 1) / 2, tmax * (u[1] + 1) / 2, taumax * u[2], taumax * u[3]]
        np.testing.assert_allclose(env.sim.applied[0, :4], expected, rtol=1e-6)


# -------------------------------------------------------------------------------------- mismatch
def plant_params(tier: str, num_envs: int = 4000, seed: int = 5, params=None, **kw) -> np.ndarray:
    """Plant parameters (N, 10) (PARAM_FIELDS order) of num_envs episodes."""
    params = SoftPVTOLParams() if params is None else params
    venv = SoftPVTOLVectorEnv(num_envs=num_envs, tier=tier, params=params, **kw)
    venv.reset(seed=seed)
    return np.array(venv.sim.P)


def _ks_uniform(x: np.ndarray, lo: float, hi: float) -> float:
    """Kolmogorov-Smirnov distance of the sample x from U(lo, hi)."""
    x = np.sort((x - lo) / (hi - lo))
    n = x.size
    i = np.arange(1, n + 1)
    return float(max((i / n - x).max(), (x - (i - 1) / n).max()))


@pytest.mark.parametrize(
    "tier,scale,kw",
    [("mismatch", 0.2, {}), ("hard", 0.2, {}), ("nominal", 0.1, {"tier_options": {"mismatch_scale": 0.1}}),
     ("mismatch", 0.2, {"params": SoftPVTOLParams(m=3.0, I_l=0.2, l_r=0.7, epsilon=0.05, g=9.81)})],
)
def test_mismatch_ranges(tier, scale, kw):
    """Each of m, m_l, m_r, I, I_l, I_r, l_l, l_r is scaled by U(1 - s, 1 + s) per episode,
    independently; g and epsilon unchanged. n = 4000 episodes: KS distance below the 1e-6 critical
    value sqrt(ln(2 / 1e-6) / (2 n)) (= 0.043); mean within Z SE = Z s / sqrt(3 n); pairwise correlations
    within Z / sqrt(n)."""
    p = kw.get("params", SoftPVTOLParams())
    P = plant_params(tier, **kw)
    n = P.shape[0]
    assert P.shape[1] == len(FIELDS)
    cols = [FIELDS.index(f) for f in MISMATCH_FIELDS]
    X = P[:, cols] / p.array[cols]
    assert (X >= 1 - scale).all() and (X <= 1 + scale).all()
    assert X.min(axis=0).max() < 1 - 0.99 * scale and X.max(axis=0).min() > 1 + 0.99 * scale  # the whole range
    ks_crit = math.sqrt(math.log(2 / 1e-6) / (2 * n))
    for j, name in enumerate(MISMATCH_FIELDS):
        ks = _ks_uniform(X[:, j], 1 - scale, 1 + scale)
        assert ks < ks_crit, f"{name}: KS distance {ks:.4f} from U({1 - scale}, {1 + scale}) (critical {ks_crit:.4f})"
        assert abs(X[:, j].mean() - 1) < Z * scale / math.sqrt(3 * n), name
    C = np.corrcoef(X.T)
    assert (np.abs(C - np.eye(len(cols))) < Z / math.sqrt(n)).all(), "mismatch factors correlated"
    for name in ("g", "epsilon"):
        assert (P[:, FIELDS.index(name)] == getattr(p, name)).all(), name


@pytest.mark.parametrize("tier", ["nominal", "wind", "noisy"])
def test_no_mismatch_outside_mismatch_tiers(tier):
    assert (plant_params(tier, num_envs=16) == SoftPVTOLParams().array).all()


def test_mismatch_redrawn_per_episode():
    """Every reset draws new plant parameters (single env: plant_params changes between episodes)."""
    env = SoftPVTOLEnv(tier="mismatch")
    draws = set()
    for s in range(5):
        env.reset(seed=s)
        draws.add(env.plant_params.m)
        env.reset()
        draws.add(env.plant_params.m)
    assert len(draws) == 10


def test_tier_values_report_what_is_on():
    """EnvConfig.tier_values: the documented defaults for the effects a tier switches on, 0 for the
    others (the correlation time is kept); an option given by hand switches its effect on."""
    defaults = dict(mismatch_scale=0.2, wind_std=3.0, obs_noise_scale=1.0, actuator_time_constant=0.05)
    on = {"nominal": (), "mismatch": ("mismatch_scale",), "wind": ("wind_std",),
          "noisy": ("obs_noise_scale", "actuator_time_constant"), "hard": tuple(defaults)}
    for tier, keys in on.items():
        tv = SoftPVTOLEnv(tier=tier).config.tier_values
        for k, v in defaults.items():
            assert tv[k] == (v if k in keys else 0.0), (tier, k)
        assert tv["wind_correlation_time"] == 1.0
    tv = SoftPVTOLEnv(tier="nominal", tier_options={"wind_std": 1.0}).config.tier_values
    assert tv["wind_std"] == 1.0 and tv["mismatch_scale"] == 0.0
