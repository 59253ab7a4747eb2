"""One evaluator for every policy with a stable-baselines3 ``predict`` (learned or analytic).

Episodes are fixed and seeded: evaluation episode i of a call with ``seed`` is sub-env i of the
native vector env reset with ``seed`` (so it gets seed + i), the same for every policy. Training seeds
live below :data:`EVAL_SEED_OFFSET`; evaluation seeds start at it, so the two never overlap. Three ranges of
evaluation seeds, each used for one thing only: the leaderboard's *test* episodes (:data:`EVAL_SEED_OFFSET`
+ i, 1,000,000 + i), its *selection* episodes, on which each side's strongest entry is chosen (2,000,000 + i),
and the *tuning* range (:data:`TUNING_SEED` + i, 3,000,000 + i) on which every sweep, tolerance and gain choice
of the project is made, so that nothing is tuned on the episodes it is reported on.

Per-episode metrics (all computed on the true, noise-free state until the episode ends). The position
error of control step k (k = 0, 1, ...) is e_k = |(x, z) - (x_ref, z_ref)| after that step, at time
t = (k + 1) dt:

* ``return``: sum of rewards;
* ``rms_position_error`` [m]: RMS of e_k over the steps the episode lived (the whole episode);
* ``rms_position_error_transient`` [m]: RMS of e_k over the first quarter of the episode's full time limit
  (steps k < L // 4, L = the time limit in control steps: hover 1,000, track_random 2,000, track_paper
  4,000 at dt = 0.01 s; i.e. t in (0, T/4]);
* ``rms_position_error_steady`` [m]: RMS of e_k over the last half (steps k >= L - L // 2: t in (T/2, T]);
* ``max_position_error_final_5s`` [m]: max of e_k over the last 5 s (steps k >= L - round(5 s / dt); the
  whole episode if it is shorter);
* ``rms_attitude_error`` [rad]: RMS over steps of the wrapped theta - theta_ref;
* ``control_effort``: mean over steps of mean(a_n^2), the env's effort measure (see the env's
  Rewards section: applied actuators normalised by their limits, relative to hover thrust), clipped at 1;
* ``fraction_within_1cm``: the share of the episode's time limit (its L control steps) with e_k below
  :data:`TOLERANCE_M` (1 cm): whether the controller is good enough, not only how exact. The steps a crashed
  episode did not live count as outside, so a crash lowers it and it is never missing;
* ``crashed``: the episode terminated (any termination reason) before its time limit;
* ``length``: number of control steps;
* ``compute_us_per_step`` [us] (only with ``timing=True``): the policy's own time per control step: the
  wall time of each ``policy.predict`` call (``time.perf_counter`` around it), divided by the number of
  envs it acted for (all the episodes of the call: they run as one batch); the median over the episode's
  steps (the first call of a process can include one-off compilation). For a batched ``predict`` (the
  learned networks, the vectorised passivity controller) it is the per-env share of one batch of
  ``episodes`` envs, for a policy that loops over the envs (MPC: one solve per env) the time per env.
  ``compute_us_per_step_p99`` and ``compute_us_per_step_max`` [us]: the 99th percentile and the maximum of
  the same per-step times (the maximum includes one-off costs such as a first call's compilation).
  Wall time depends on the machine and its load; it is not a reproducible number and is left out of
  the default (reproducible) output.

Crashed windows: a window the episode did not live through to its end (it terminated before the window's
last step) has the value ``None`` (JSON null) and the episode has ``crashed: True``; a window that ended
before the crash keeps its measured value (a track_random episode that crashes at 12 s keeps its 0-5 s
transient). The last-half and final-5 s windows end with the time limit, so every crashed episode has them
``None``. Statistics rank a crashed window as worse than any finite value (:func:`window_scores`: +inf):
a crashed episode never makes an entry look better, and never drops out of its sample.
"""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np

from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

EVAL_SEED_OFFSET = 1_000_000
#: the first seed of the tuning range (sweeps, tolerances, gains): disjoint from the test and selection episodes
TUNING_SEED = 3_000_000
#: the metrics of every episode (a crashed window is None; see the module docstring)
WINDOW_METRICS = ("rms_position_error_transient", "rms_position_error_steady", "max_position_error_final_5s")
EPISODE_METRICS = ("return", "rms_position_error", *WINDOW_METRICS, "rms_attitude_error", "control_effort",
                   "fraction_within_1cm", "crashed", "length")
#: the position tolerance of ``fraction_within_1cm`` [m]
TOLERANCE_M = 0.01
#: measured only with ``run_episodes(..., timing=True)``: wall time, not reproducible
TIMING_METRICS = ("compute_us_per_step", "compute_us_per_step_p99", "compute_us_per_step_max")
#: the per-robot compute of a leaderboard episode [us]: its run's figure on its task and tier
#: (:func:`per_robot_compute_us`, a pass of its own); wall time, not reproducible
COMPUTE_SINGLE = "compute_us_single"
#: the length of the final window [s]
FINAL_WINDOW_SECONDS = 5.0
_EFFORT_WEIGHT = 0.1  # the env's effort reward term is -0.1 * min(mean(a_n^2), 1)


def window_steps(max_steps: int, dt: float) -> dict[str, tuple[int, int]]:
    """The control steps [start, end) of each window of an episode of ``max_steps`` steps of ``dt`` s:
    ``transient`` (the first quarter), ``steady`` (the last half), ``final_5s`` (the last 5 s, the whole
    episode if shorter). Each holds at least one step."""
    if max_steps < 1 or not dt > 0:
        raise ValueError(f"max_steps must be >= 1 and dt > 0, got {max_steps} and {dt}")
    final = min(max_steps, max(1, round(FINAL_WINDOW_SECONDS / dt)))
    return {"transient": (0, max(1, max_steps // 4)),
            "steady": (max_steps - max(1, max_steps // 2), max_steps),
            "final_5s": (max_steps - final, max_steps)}


def run_episodes(policy, action_mode: str, task: str, tier: str, episodes: int, seed: int,
                 env_kwargs: dict | None = None, timing: bool = False, reset_options: dict | None = None) -> list[dict]:
    """Run ``policy.predict`` (deterministic) on ``episodes`` seeded episodes in parallel; one dict of
    :data:`EPISODE_METRICS` per episode (and :data:`TIMING_METRICS` with ``timing=True``). ``reset_options``:
    the env's ``reset(options=...)`` for every episode (e.g. ``{"q0": ...}``, a start of one's own)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env = SoftPVTOLVectorEnv(num_envs=episodes, action_mode=action_mode, task=task, tier=tier, **(env_kwargs or {}))
    sim = env.sim
    limit = int(sim.max_steps)
    windows = window_steps(limit, float(sim.dt))
    (t0, t1), (s0, s1), (f0, f1) = windows["transient"], windows["steady"], windows["final_5s"]
    obs, _ = env.reset(seed=seed, options=reset_options)
    n = episodes
    ret, sq_pos, sq_att, effort, length, sq_tr, sq_st, max_fin, within = (np.zeros(n) for _ in range(9))
    done, crashed, start = np.zeros(n, bool), np.zeros(n, bool), np.ones(n, bool)
    seconds = []  # wall time of each predict call
    while not done.all():
        tic = time.perf_counter()
        action, _ = policy.predict(obs, episode_start=start, deterministic=True)
        seconds.append(time.perf_counter() - tic)
        start[:] = False
        previous = obs
        obs, reward, term, trunc, info = env.step(action)
        live = ~done
        q = sim.q
        e_pos = q[:, :2] - sim.qr[:, :2]
        e_att = np.arctan2(np.sin(q[:, 2] - sim.qr[:, 2]), np.cos(q[:, 2] - sim.qr[:, 2]))
        sq = np.sum(e_pos ** 2, axis=1)
        k = length.copy()  # the step index of each episode (before this step is counted)
        ret[live] += reward[live]
        sq_pos[live] += sq[live]
        sq_tr[live & (k >= t0) & (k < t1)] += sq[live & (k >= t0) & (k < t1)]
        sq_st[live & (k >= s0) & (k < s1)] += sq[live & (k >= s0) & (k < s1)]
        fin = live & (k >= f0) & (k < f1)
        max_fin[fin] = np.maximum(max_fin[fin], np.sqrt(sq[fin]))
        sq_att[live] += e_att[live] ** 2
        within[live & (sq < TOLERANCE_M ** 2)] += 1
        effort[live] += -info["reward_terms"]["effort"][live] / _EFFORT_WEIGHT
        length[live] += 1
        crashed |= term & live
        done |= term | trunc
        if done.any() and not done.all():
            # a finished episode's entry is never scored again; the policy (which acts on the whole batch) gets
            # its last observation of a running episode instead of the terminal one, which may lie outside
            # what an analytic controller accepts (a diverged episode's arms bent past 2 pi)
            obs = np.where(done[:, None], previous, obs)
    env.close()
    steps = np.maximum(length, 1)
    per_env_us = np.asarray(seconds) / n * 1e6

    def window(i: int, value: float, end: int):
        return float(value) if length[i] >= end else None  # not lived through: crashed (module docstring)

    out = []
    for i in range(n):
        ep = {
            "return": float(ret[i]),
            "rms_position_error": float(np.sqrt(sq_pos[i] / steps[i])),
            "rms_position_error_transient": window(i, np.sqrt(sq_tr[i] / (t1 - t0)), t1),
            "rms_position_error_steady": window(i, np.sqrt(sq_st[i] / (s1 - s0)), s1),
            "max_position_error_final_5s": window(i, max_fin[i], f1),
            "rms_attitude_error": float(np.sqrt(sq_att[i] / steps[i])),
            "control_effort": float(effort[i] / steps[i]),
            "fraction_within_1cm": float(within[i] / limit),
            "crashed": bool(crashed[i]),
            "length": int(length[i]),
        }
        if timing:
            own = per_env_us[: int(steps[i])]
            ep["compute_us_per_step"] = float(np.median(own))
            ep["compute_us_per_step_p99"] = float(np.percentile(own, 99))
            ep["compute_us_per_step_max"] = float(own.max())
        out.append(ep)
    return out


@contextlib.contextmanager
def one_torch_thread():
    """torch on one thread inside the block (restored after), if torch is loaded: a learned policy's forward pass
    then runs in the calling thread, as the compiled kernels of one observation do."""
    torch = sys.modules.get("torch")  # not imported for a policy without it (it takes seconds)
    before = None if torch is None else torch.get_num_threads()
    if torch is not None:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if torch is not None:
            torch.set_num_threads(before)


def compute_us_single(policy, observations, repeats: int = 3) -> float:
    """The median wall time [us] of ``policy.predict`` on one observation at a time: the latency of the controller
    of one robot, measured in a pass of its own (not during an evaluation of many episodes at once).

    ``observations`` (n, obs_dim): the observations of a real episode, in order, as the robot met them, so that a
    controller with memory (an MPC's warm start and disturbance estimate, an integral loop's integrator, a learned
    policy's frame stack) does each step's work as it did in the closed loop. One untimed call first (observation
    0, ``episode_start`` true: any one-off compilation), then ``repeats`` passes over the observations in order,
    each starting the policy's memory for one robot anew (``episode_start`` true on observation 0) and each call
    ``predict(observations[i], ...)`` on the observation (obs_dim,) alone, timed with ``time.perf_counter`` around
    the call. The median over the ``repeats * n`` calls leaves out the occasional call that the OS interrupted.
    Runs in the calling thread: torch on one thread (restored after); the package's compiled kernels split only
    batches of 512 rows and more over threads, so one observation never is. Wall time: it depends on the machine
    and its load (say which, beside the figure)."""
    obs = np.asarray(observations)
    if obs.ndim != 2 or obs.shape[0] < 1:
        raise ValueError(f"observations must be an array (n, obs_dim) of n >= 1 observations, got shape {obs.shape}")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    rows = list(obs)
    seconds = np.empty(repeats * len(rows))
    start = np.ones(1, dtype=bool)
    with one_torch_thread():
        policy.predict(rows[0], episode_start=start, deterministic=True)
        i = 0
        for _ in range(repeats):
            for j, row in enumerate(rows):
                tic = time.perf_counter()
                policy.predict(row, episode_start=start if j == 0 else None, deterministic=True)
                seconds[i] = time.perf_counter() - tic
                i += 1
    return float(np.median(seconds) * 1e6)


#: the per-robot compute pass replays at most this many observations of the first episode, from its start, in order
#: (10 s of control at 100 Hz: a tracking task's transient and the start of its steady state)
COMPUTE_OBSERVATIONS = 1000
#: how the per-robot compute pass is measured (recorded in each job's result: a result measured another way, or
#: before this was recorded, has its pass run again)
COMPUTE_PASS = (f"closed-loop order, first {COMPUTE_OBSERVATIONS} observations of test episode 0; lean pass: "
                "each input's weights a view, a frame stack inside the compiled call")


def episode_observations(policy, action_mode: str, task: str, tier: str, seed: int,
                         env_kwargs: dict | None = None, steps: int | None = None) -> np.ndarray:
    """The observations (steps, obs_dim) that ``policy`` acts on in evaluation episode 0 of ``seed`` (the episode
    :func:`run_episodes` runs as sub-env 0), in order, run alone in an env of its own until it ends or for at most
    ``steps`` steps (None: until it ends)."""
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=action_mode, task=task, tier=tier, **(env_kwargs or {}))
    obs, _ = env.reset(seed=seed)
    seen, start, done = [], np.ones(1, bool), False
    while not done and (steps is None or len(seen) < steps):
        seen.append(obs[0].copy())
        action, _ = policy.predict(obs, episode_start=start, deterministic=True)
        start[:] = False
        obs, _, term, trunc, _ = env.step(action)
        done = bool(term[0] or trunc[0])
    env.close()
    return np.asarray(seen)


def per_robot_compute_us(policy, action_mode: str, task: str, tier: str, seed: int, env_kwargs: dict | None = None,
                         observations: int = COMPUTE_OBSERVATIONS, repeats: int = 3) -> float:
    """The per-robot compute of ``policy`` on a task and tier [us], measured in a pass of its own:
    :func:`compute_us_single` on the first ``observations`` observations of evaluation episode 0 of ``seed``
    (:func:`episode_observations`; fewer if it ends sooner), in the order of its closed loop. Wall time: machine-
    and load-dependent."""
    if isinstance(observations, bool) or not isinstance(observations, int) or observations < 1:
        raise ValueError(f"observations must be an integer >= 1, got {observations!r}")
    seen = episode_observations(policy, action_mode, task, tier, seed, env_kwargs, steps=observations)
    return compute_us_single(policy, seen, repeats=repeats)


def without_timing(episode: dict) -> dict:
    """``episode`` without its wall-time metrics (:data:`TIMING_METRICS`, :data:`COMPUTE_SINGLE`): what a re-run
    reproduces exactly."""
    return {k: v for k, v in episode.items() if k not in TIMING_METRICS and k != COMPUTE_SINGLE}


def window_scores(episodes: list[dict], key: str) -> np.ndarray:
    """The values of ``key`` over ``episodes``, a crashed window (None) as +inf: worse than any value."""
    return np.array([np.inf if e[key] is None else float(e[key]) for e in episodes], dtype=float)


def summarize(episodes: list[dict]) -> dict:
    """Means over episodes of :data:`EPISODE_METRICS` (``crash_rate`` for ``crashed``). A window's mean is
    None where any episode crashed in it (a crashed window is worse than any value: the mean is unbounded);
    ``crashed_<window>`` counts those episodes. With timing: ``median_compute_us_per_step`` over episodes."""
    out = {"episodes": len(episodes)}
    for key in EPISODE_METRICS:
        if key in WINDOW_METRICS:
            vals = window_scores(episodes, key)
            out[f"mean_{key}"] = float(vals.mean()) if np.isfinite(vals).all() else None
            out[f"crashed_{key}"] = int(np.sum(~np.isfinite(vals)))
            continue
        vals = np.array([e[key] for e in episodes], dtype=float)
        out["crash_rate" if key == "crashed" else f"mean_{key}"] = float(vals.mean())
    key = TIMING_METRICS[0]
    if all(key in e for e in episodes):
        out[f"median_{key}"] = float(np.median([e[key] for e in episodes]))
    return out


def identical_episodes(episodes: list[dict]) -> bool:
    """Whether every episode has the same metrics (all of :data:`EPISODE_METRICS`, exactly; the wall-time
    :data:`TIMING_METRICS` aside): a deterministic task and tier gives the same episode whatever its seed."""
    first = {k: episodes[0].get(k) for k in EPISODE_METRICS}  # (.get: results from before the windows lack them)
    return all({k: e.get(k) for k in EPISODE_METRICS} == first for e in episodes[1:])


def evaluate(policy, action_mode: str, task: str, tier: str, episodes: int, seed: int,
             env_kwargs: dict | None = None, timing: bool = False) -> dict:
    """``{"episodes": [...], "summary": {...}}`` of :func:`run_episodes` and :func:`summarize`."""
    eps = run_episodes(policy, action_mode, task, tier, episodes, seed, env_kwargs, timing=timing)
    return {"episodes": eps, "summary": summarize(eps)}
