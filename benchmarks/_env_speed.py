"""Items 1-3: the env's speed against gymnasium's own envs, and the passivity controller against one env
step (benchmarks/run.py)."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

from benchmarks._common import fmt_rate, fmt_time, interleaved, median, ratios, table, verdict

# ----------------------------------------------------------------------------- 1. single env
#: the targets: SoftPVTOL-v0 / Pendulum-v1 (random actions, resets counted), idle and with one core busy
SINGLE_TARGET = 0.6
SINGLE_BUSY_TARGET = 1.0


def _step_timer(env, n_steps: int, seed: int):
    """A callable timing n_steps random-action steps of env, the resets of the episodes that end
    included (as a training loop pays them); returns s/step."""
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(256)]
    env.reset(seed=seed)

    def run() -> float:
        t0 = time.perf_counter()
        for k in range(n_steps):
            _, _, term, trunc, _ = env.step(actions[k & 255])
            if term or trunc:
                env.reset()
        return (time.perf_counter() - t0) / n_steps

    return run


_SPIN = "import time\nt = time.time() + {seconds}\nwhile time.time() < t:\n    pass\n"


def _busy_core(seconds: float):
    """A process that keeps one core busy for ``seconds`` (a pure-Python spin loop)."""
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-c", _SPIN.format(seconds=seconds)])


def _interleaved_one_core_busy(cases: dict, reps: int, warm_up: bool = False) -> dict:
    """:func:`interleaved` timings of ``cases`` while another process keeps one core busy (after one untimed call
    of each with ``warm_up``)."""
    spin = _busy_core(600.0)
    try:
        time.sleep(0.2)
        if warm_up:
            for fn in cases.values():
                fn()
        return interleaved(cases, reps)
    finally:
        spin.kill()
        spin.wait()


def bench_single(quick: bool) -> dict:
    n_steps, reps = (300, 5) if quick else (3000, 15)
    envs = {
        "SoftPVTOL-v0": gym.make("SoftPVTOL-v0"),
        "Pendulum-v1": gym.make("Pendulum-v1"),
        "Acrobot-v1": gym.make("Acrobot-v1"),
    }
    cases = {name: _step_timer(env, n_steps, seed=i) for i, (name, env) in enumerate(envs.items())}
    for fn in cases.values():  # warm-up
        fn()
    t = interleaved(cases, reps)
    pair = {k: cases[k] for k in ("SoftPVTOL-v0", "Pendulum-v1")}
    busy = _interleaved_one_core_busy(pair, reps)  # the same pair again while another process keeps a core busy
    r_pend = ratios(t["SoftPVTOL-v0"], t["Pendulum-v1"])
    r_busy = ratios(busy["SoftPVTOL-v0"], busy["Pendulum-v1"])
    r_acro = ratios(t["SoftPVTOL-v0"], t["Acrobot-v1"])
    rows = [[name, fmt_time(median(v)), fmt_time(median(busy[name])) if name in busy else "-"] for name, v in t.items()]
    text = table(["env (gym.make, default settings, random actions, resets counted)", "median step",
                  "median step, one core busy"], rows)
    text += "\n\n" + table(
        ["ratio", "value", "target", "verdict"],
        [["SoftPVTOL-v0 / Pendulum-v1", f"{r_pend:.2f}x", f"<= {SINGLE_TARGET}x", verdict(r_pend <= SINGLE_TARGET)],
         ["SoftPVTOL-v0 / Pendulum-v1, another process keeping one core busy", f"{r_busy:.2f}x",
          f"<= {SINGLE_BUSY_TARGET}x", verdict(r_busy <= SINGLE_BUSY_TARGET)],
         ["SoftPVTOL-v0 / Acrobot-v1 (RK4 too)", f"{r_acro:.2f}x", "-", "n/a"]])
    for env in envs.values():
        env.close()
    return {
        "title": "1. Single-env step latency",
        "text": text,
        "seconds_per_step": {k: median(v) for k, v in t.items()},
        "seconds_per_step_busy": {k: median(v) for k, v in busy.items()},
        "ratio_vs_pendulum": r_pend,
        "ratio_vs_pendulum_busy": r_busy,
        "ratio_vs_acrobot": r_acro,
        "targets": {
            "ratio_vs_pendulum": {"value": r_pend, "target": f"<= {SINGLE_TARGET}", "pass": r_pend <= SINGLE_TARGET},
            "ratio_vs_pendulum_busy": {"value": r_busy, "target": f"<= {SINGLE_BUSY_TARGET}",
                                       "pass": r_busy <= SINGLE_BUSY_TARGET},
        },
    }


# ----------------------------------------------------------------------------- 2. vector env
#: the target at N = 4096 with another process keeping one core busy: SoftPVTOL / CartPoleVectorEnv
VECTOR_BUSY_TARGET = 0.15
def _vector_timer(env, n: int, n_steps: int, seed: int, discrete: bool):
    """A callable timing n_steps batched random-action steps; returns env-steps per second."""
    rng = np.random.default_rng(seed)
    if discrete:
        actions = [rng.integers(0, 2, n) for _ in range(4)]
    else:
        shape = env.action_space.shape
        actions = [rng.uniform(-1.0, 1.0, shape).astype(np.float32) for _ in range(4)]
    env.reset(seed=seed)
    env.step(actions[0])

    def run() -> float:
        t0 = time.perf_counter()
        for k in range(n_steps):
            env.step(actions[k & 3])
        return n * n_steps / (time.perf_counter() - t0)

    return run


def bench_vector(quick: bool) -> dict:
    from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

    sizes = (1, 16, 256, 4096, 65536)
    sync_max = 256
    reps = 3 if quick else 7
    budget = 2e4 if quick else 4e5  # env-steps per timed repetition (at least 5 batched steps)
    results = {}
    rows = []
    for n in sizes:
        n_steps = max(5, int(budget // n)) if n > 1 else (200 if quick else 3000)
        cases = {
            "softpvtol": _vector_timer(
                gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="vector_entry_point"),
                n, n_steps, 0, False),
            "cartpole": _vector_timer(CartPoleVectorEnv(num_envs=n), n, n_steps, 1, True),
        }
        if n <= sync_max:
            sync = gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="sync")
            cases["sync"] = _vector_timer(sync, n, max(3, n_steps // (50 if n > 1 else 1)), 2, False)
        for fn in cases.values():
            fn()
        t = interleaved(cases, reps)
        entry = {k: median(v) for k, v in t.items()}
        entry["ratio_vs_cartpole"] = ratios(t["softpvtol"], t["cartpole"])
        if "sync" in t:
            entry["ratio_vs_sync"] = ratios(t["softpvtol"], t["sync"])
        results[n] = entry
        rows.append([n, fmt_rate(entry["softpvtol"]), fmt_rate(entry["cartpole"]), f"{entry['ratio_vs_cartpole']:.2f}x",
                     fmt_rate(entry["sync"]) if "sync" in entry else "-",
                     f"{entry['ratio_vs_sync']:.0f}x" if "ratio_vs_sync" in entry else "-"])
    text = table(["N", "SoftPVTOL vector env", "CartPoleVectorEnv", "ratio", "SoftPVTOL sync (make_vec)",
                  "ratio vs sync"], rows)
    r4096 = results[4096]
    r256 = results[256]
    # N = 4096 again while another process keeps one core busy (the vector env's threads then share a core)
    n = 4096
    n_steps = max(5, int(budget // n))
    vec = gym.make_vec("SoftPVTOL-v0", num_envs=n, vectorization_mode="vector_entry_point")
    pair = {"softpvtol": _vector_timer(vec, n, n_steps, 0, False),
            "cartpole": _vector_timer(CartPoleVectorEnv(num_envs=n), n, n_steps, 1, True)}
    busy = _interleaved_one_core_busy(pair, reps, warm_up=True)
    r4096["busy"] = {k: median(v) for k, v in busy.items()}
    r4096["ratio_vs_cartpole_busy"] = ratios(busy["softpvtol"], busy["cartpole"])
    text += (f"\n\nN = 4096 with another process keeping one core busy: SoftPVTOL "
             f"{fmt_rate(r4096['busy']['softpvtol'])}, CartPoleVectorEnv {fmt_rate(r4096['busy']['cartpole'])}, "
             f"ratio {r4096['ratio_vs_cartpole_busy']:.2f}x.")
    checks = [
        ["N = 4096 throughput", fmt_rate(r4096["softpvtol"]), ">= 5 M/s on 2 cores",
         verdict(r4096["softpvtol"] >= 5e6)],
        ["N = 4096 / CartPoleVectorEnv", f"{r4096['ratio_vs_cartpole']:.2f}x", ">= 0.25x",
         verdict(r4096["ratio_vs_cartpole"] >= 0.25)],
        ["N = 4096 / CartPoleVectorEnv, one core busy", f"{r4096['ratio_vs_cartpole_busy']:.2f}x",
         f">= {VECTOR_BUSY_TARGET}x", verdict(r4096["ratio_vs_cartpole_busy"] >= VECTOR_BUSY_TARGET)],
        ["N = 256 / sync vector env", f"{r256['ratio_vs_sync']:.0f}x", ">= 50x", verdict(r256["ratio_vs_sync"] >= 50)],
    ]
    text += "\n\n" + table(["target", "value", "target", "verdict"], checks)
    return {
        "title": "2. Vector-env throughput (env-steps/s, random actions, default settings)",
        "text": text,
        "by_num_envs": {str(k): v for k, v in results.items()},
        "targets": {
            "steps_per_second_4096": {"value": r4096["softpvtol"], "target": ">= 5e6",
                                      "pass": r4096["softpvtol"] >= 5e6},
            "ratio_vs_cartpole_4096": {"value": r4096["ratio_vs_cartpole"], "target": ">= 0.25",
                                       "pass": r4096["ratio_vs_cartpole"] >= 0.25},
            "ratio_vs_cartpole_4096_busy": {"value": r4096["ratio_vs_cartpole_busy"],
                                            "target": f">= {VECTOR_BUSY_TARGET}",
                                            "pass": r4096["ratio_vs_cartpole_busy"] >= VECTOR_BUSY_TARGET},
            "ratio_vs_sync_256": {"value": r256["ratio_vs_sync"], "target": ">= 50",
                                  "pass": r256["ratio_vs_sync"] >= 50},
        },
    }


# -------------------------------------------------------------------- 3. controller + allocation
def _step_or_reset(env, action) -> None:
    """One step of a single env, and a reset if its episode ended (never step a finished episode)."""
    _, _, term, trunc, _ = env.step(action)
    if term or trunc:
        env.reset()


def _calls_timer(fn, n_calls: int):
    def run() -> float:
        t0 = time.perf_counter()
        for _ in range(n_calls):
            fn()
        return (time.perf_counter() - t0) / n_calls

    return run


#: the target of item 3: a residual-mode env step (the default agent's, its base controller included) against an
#: actuators-mode env step, vector env, N = 4096 (the controllers' own ratios are reported without a target)
RESIDUAL_STEP_TARGET = 2.5

#: the timed case of each ratio of item 3 (the residual mode's is the difference of two env steps)
_TIMED = {"ratio_policy": "PassivityPolicy.predict", "ratio_controller": "PassivityController()",
          "ratio_policy_integral": "PassivityPolicy.predict (integral)",
          "ratio_policy_extended": "ExtendedPolicy.predict"}

#: Item 3 times each controller along its own closed loop, not on one observation given again and again: the
#: algebraic loop of the actuated loops (body rows -> allocation -> arm references, solved to 1e-10 rad from the
#: last two steps' solutions extrapolated) depends on where the loop has been: along a closed loop it takes two
#: passes in steady state and more in an episode's first 100 steps (about three and a half). Windows of WINDOW
#: steps start at the steps STARTS of a hover episode (nominal tier, seed 0): a single state's windows cover the
#: whole episode, the batch's sample it.
STARTS = tuple(range(0, 1000, 100))
WINDOW = {"single": 100, "batched": 10}


class _ClosedLoop:
    """The inputs of a controller along its own closed loop, and copies of it at each window's start: replaying
    a window calls a copy on the inputs it met there, in order (the same calls as in the loop).

    ``policy``: a policy (its ``predict`` acts on ``env``, an actuators-mode vector env), or a
    ``PassivityController`` that shadows the base controller of ``env`` (residual mode, zero residual actions):
    it is called on the env's measured state and reference (that controller's inputs), and the env steps itself.
    ``single``: one state (``env`` has one sub-env; inputs of shape (18,) or (5,))."""

    def __init__(self, env, policy, starts: tuple[int, ...], window: int, single: bool):
        import copy

        self.policy, self.single = policy, single
        self.controller = not hasattr(policy, "predict")
        #: per window: (the controller as it was at its start, the calls' arguments, their outputs in the loop)
        self.windows: list[tuple[object, list[tuple], list[np.ndarray]]] = []
        zeros = np.zeros(env.action_space.shape, dtype=np.float32)
        obs, _ = env.reset(seed=0)
        episode_start = np.ones(env.num_envs, dtype=bool)
        last = max(starts) + window
        for k in range(last):
            if k in starts:
                self.windows.append((copy.deepcopy(policy), [], []))
            if self.controller:
                sim = env.sim
                rows = [x.copy() for x in (sim.qm, sim.qdm, sim.qr, sim.qdr, sim.qddr)]
                call = tuple(x[0] for x in rows) if single else tuple(rows)
                output = policy(*call).actuators
                action = zeros
            else:
                call = (obs[0].copy(),) if single else (obs.copy(), None, episode_start)  # (obs, state, episode_start)
                output = policy.predict(*call)[0]
                action = output[None] if single else output
            for s, (_, calls, outputs) in zip(starts, self.windows):
                if s <= k < s + window:
                    calls.append(call)
                    outputs.append(np.array(output))  # (a copy: a policy may return a kept buffer)
            obs, _, term, trunc, _ = env.step(action)
            episode_start = term | trunc
            if single and episode_start[0] and k + 1 < last:
                raise RuntimeError(f"{type(policy).__name__}: the hover episode ended at step {k + 1}, before the "
                                   f"last window's end ({last})")

    def caller(self, snapshot):
        """A fresh copy of a window's controller, to be called as in the loop: fn(*call) (``output`` reads the
        action, or the controller's actuators, from what it returns)."""
        import copy

        p = copy.deepcopy(snapshot)
        return p if self.controller else p.predict

    def output(self, result) -> np.ndarray:
        return result.actuators if self.controller else result[0]

    def timer(self):
        """A callable returning the mean seconds per call over every window, each replayed by a fresh copy of
        the controller as it was at the window's start (copying is not timed)."""

        def run() -> float:
            total, count = 0.0, 0
            for snapshot, calls, _ in self.windows:
                fn = self.caller(snapshot)
                t0 = time.perf_counter()
                for call in calls:
                    fn(*call)
                total += time.perf_counter() - t0
                count += len(calls)
            return total / count

        return run


def bench_controller(quick: bool) -> dict:
    from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
    from softpvtol_gym.control import PassivityController

    reps = 5 if quick else 11
    results = {}
    rows = []
    for label, n, calls in (("single", 1, 300 if quick else 3000), ("batched", 4096, 3 if quick else 20)):
        kw = dict(task="hover", tier="nominal")
        act = SoftPVTOLVectorEnv(num_envs=n, **kw)  # the reference: one step of the default (actuators) env
        res = SoftPVTOLVectorEnv(num_envs=n, action_mode="residual", **kw)
        for e in (act, res):
            e.reset(seed=0)
        rng = np.random.default_rng(0)
        # actions near hover in both modes (thrusts at the hover thrust T_max / 3, small corrections), so
        # that both envs reset about as rarely and the difference of their steps is the controller
        a_act = (np.array([-1 / 3, -1 / 3, 0.0, 0.0]) + rng.uniform(-0.05, 0.05, (n, 4))).astype(np.float32)
        a_res = rng.uniform(-0.05, 0.05, (n, 5)).astype(np.float32)
        # each controller along its own closed loop (see STARTS): the policies act on an actuators-mode env, the
        # controller shadows the residual-mode env's base controller
        starts, window = ((0,), 5 if n > 1 else 50) if quick else (STARTS, WINDOW[label])
        policies = {"PassivityPolicy.predict": None, "PassivityPolicy.predict (integral)": "integral",
                    "ExtendedPolicy.predict": "extended"}
        loops = {}
        for name, loop in policies.items():
            env = SoftPVTOLVectorEnv(num_envs=n, **kw)
            loops[name] = _ClosedLoop(env, PassivityPolicy.from_env(env, loop=loop), starts, window, n == 1)
        loops["PassivityController()"] = _ClosedLoop(SoftPVTOLVectorEnv(num_envs=n, action_mode="residual", **kw),
                                                      PassivityController.from_loop("exact"), starts, window, n == 1)
        if n == 1:  # the single env through gym.make, as item 1
            single = {m: gym.make("SoftPVTOL-v0", action_mode=m) for m in ("actuators", "residual")}
            for e in single.values():
                e.reset(seed=0)
            # loop variables bound as defaults (ruff B023); an episode that ends is reset (rarely, near hover)
            step_act = _calls_timer(lambda s=single, a=a_act: _step_or_reset(s["actuators"], a[0]), calls)
            step_res = _calls_timer(lambda s=single, a=a_res: _step_or_reset(s["residual"], a[0]), calls)
        else:
            step_act = _calls_timer(lambda e=act, a=a_act: e.step(a), calls)
            step_res = _calls_timer(lambda e=res, a=a_res: e.step(a), calls)
        cases = {"env step (actuators)": step_act, "env step (residual)": step_res,
                 **{name: loop.timer() for name, loop in loops.items()}}
        for fn in cases.values():
            fn()
        t = interleaved(cases, reps)
        base = t["env step (actuators)"]
        extra = [r - a for r, a in zip(t["env step (residual)"], base)]
        entry = {k: median(v) for k, v in t.items()}
        entry["residual_extra"] = median(extra)
        entry["ratio_residual_step"] = ratios(t["env step (residual)"], base)
        entry["ratio_residual_extra"] = median([e / b for e, b in zip(extra, base)])
        entry["ratio_policy"] = ratios(t["PassivityPolicy.predict"], base)
        entry["ratio_controller"] = ratios(t["PassivityController()"], base)
        entry["ratio_policy_integral"] = ratios(t["PassivityPolicy.predict (integral)"], base)
        entry["ratio_policy_extended"] = ratios(t["ExtendedPolicy.predict"], base)
        results[label] = entry
        per = n
        for name, key in (("residual mode: extra cost of its base controller per step", "ratio_residual_extra"),
                          ("PassivityPolicy.predict", "ratio_policy"),
                          ("PassivityController call", "ratio_controller"),
                          ("PassivityPolicy.predict, integral loop", "ratio_policy_integral"),
                          ("ExtendedPolicy.predict (the extended loop)", "ratio_policy_extended")):
            value = entry["residual_extra"] if key == "ratio_residual_extra" else entry[_TIMED[key]]
            rows.append([f"{label} (N = {n})", name, fmt_time(value / per) + (" per env" if n > 1 else ""),
                         f"{entry[key]:.2f}x", "report", "n/a"])
        target = RESIDUAL_STEP_TARGET if n > 1 else None
        rows.append([f"{label} (N = {n})", "residual-mode env step (its base controller included)",
                     fmt_time(entry["env step (residual)"] / per) + (" per env" if n > 1 else ""),
                     f"{entry['ratio_residual_step']:.2f}x", f"<= {target}x" if target else "report",
                     verdict(entry["ratio_residual_step"] <= target) if target else "n/a"])
        rows.append([f"{label} (N = {n})", "one env step (actuators mode), the unit",
                     fmt_time(entry["env step (actuators)"] / per) + (" per env" if n > 1 else ""), "1.00x", "-", "-"])
    text = ("Each controller is timed along its own closed loop (a hover episode, nominal tier, seed 0): copies of it "
            "replay the episode's calls, "
            + ("in one short window (--quick)" if quick else f"in windows of {WINDOW['single']} steps (one state) and "
               f"{WINDOW['batched']} steps (batched) from steps {', '.join(map(str, STARTS[:3]))}, ..., {STARTS[-1]}")
            + ". The residual mode's base controller: the difference of a residual-mode and an actuators-mode env "
              "step (actions near hover).\n\n")
    text += table(["case", "controller + allocation", "time", "ratio to one env step", "target", "verdict"], rows)
    batched = results["batched"]["ratio_residual_step"]
    targets = {"batched_ratio_residual_step": {"value": batched, "target": f"<= {RESIDUAL_STEP_TARGET}",
                                              "pass": batched <= RESIDUAL_STEP_TARGET}}
    return {"title": "3. Passivity controller + allocation per step vs one env step", "text": text,
            "results": results, "targets": targets}
