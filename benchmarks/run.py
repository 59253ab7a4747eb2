"""Benchmark suite of issue 7: the speed of the Soft-PVTOL env measured against gymnasium's own envs.

    python benchmarks/run.py            # full run (~5 min), writes benchmarks/RESULTS.md, results.json and
                                        # time_to_beat.png, and the README's Performance table
    python benchmarks/run.py --quick    # smoke run (~1 min), same tables, few repetitions, a short train.py

Every figure is a ratio measured in one process against reference envs timed in the same run,
interleaved (A B A B ...) and summarised by medians, because absolute times on a shared machine are
not stable. Items:

1. single-env step latency: gym.make("SoftPVTOL-v0") (defaults, random actions) vs Pendulum-v1 and
   Acrobot-v1;
2. vector-env throughput at N = 1 ... 65536 vs gymnasium's CartPoleVectorEnv and vs
   gym.make_vec(..., vectorization_mode="sync") of our env;
3. passivity controller + allocation vs one env step (single and batched): the residual mode's
   extra cost, PassivityPolicy.predict, PassivityController calls;
4. PPO with the default train.py configuration: env-steps/s and the share of wall time in the env;
5. cold start: import, first reset + step in a fresh process (warm numba cache), compile time with a
   cold cache;
6. time to beat the passivity controller: `python train.py` (the default agent) in a fresh process, the
   wall-clock seconds until its periodic held-out evaluation first beats the passivity controller, and of
   the whole run; its learning curve against wall-clock seconds is plotted to time_to_beat.png.

RESULTS.md is generated: do not edit it by hand, rerun the command.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import numpy as np  # noqa: E402

from softpvtol_gym.baselines.util.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent

import gymnasium as gym  # noqa: E402

import softpvtol_gym  # noqa: E402,F401  (registers SoftPVTOL-v0)

ITEMS = ("single", "vector", "controller", "ppo", "cold_start", "time_to_beat")


# ------------------------------------------------------------------------------------ helpers
def median(xs):
    return float(statistics.median(xs))


def fmt_time(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.2f} us"
    if seconds < 1.0:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"


def fmt_rate(x: float) -> str:
    if x >= 1e6:
        return f"{x / 1e6:.2f} M/s"
    if x >= 1e3:
        return f"{x / 1e3:.1f} k/s"
    return f"{x:.0f} /s"


def verdict(ok: bool | None) -> str:
    return "n/a" if ok is None else ("PASS" if ok else "FAIL")


def interleaved(cases: dict, reps: int) -> dict[str, list[float]]:
    """Run every case once per repetition, in turn (A B C A B C ...); returns name -> per-rep values.

    A case is a callable returning the value of one repetition (e.g. seconds per step)."""
    out = {name: [] for name in cases}
    for _ in range(reps):
        for name, fn in cases.items():
            out[name].append(fn())
    return out


def ratios(a: list[float], b: list[float]) -> float:
    """Median over repetitions of a[i] / b[i] (each pair measured next to each other)."""
    return median([x / y for x, y in zip(a, b)])


def table(headers: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def machine_facts() -> dict:
    import numba
    import stable_baselines3
    import torch

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--", "softpvtol_gym", "benchmarks/run.py"],
                                    cwd=ROOT, capture_output=True, text=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        commit, dirty = "unknown", False
    return {
        "cores": os.cpu_count(),
        "cpu": cpu,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "gymnasium": gym.__version__,
        "torch": torch.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "softpvtol_gym": softpvtol_gym.__version__,
        "numba_num_threads": numba.config.NUMBA_NUM_THREADS,
        "commit": commit + (" (with uncommitted changes to softpvtol_gym/ or benchmarks/run.py)" if dirty else ""),
        "loadavg_start": list(os.getloadavg()),
    }


# ----------------------------------------------------------------------------- 1. single env
def _step_timer(env, n_steps: int, seed: int):
    """A callable timing n_steps random-action steps of env (resets excluded); returns s/step."""
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(256)]
    env.reset(seed=seed)

    def run() -> float:
        t_reset = 0.0
        t0 = time.perf_counter()
        for k in range(n_steps):
            _, _, term, trunc, _ = env.step(actions[k & 255])
            if term or trunc:
                r0 = time.perf_counter()
                env.reset()
                t_reset += time.perf_counter() - r0
        return (time.perf_counter() - t0 - t_reset) / n_steps

    return run


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
    r_pend = ratios(t["SoftPVTOL-v0"], t["Pendulum-v1"])
    r_acro = ratios(t["SoftPVTOL-v0"], t["Acrobot-v1"])
    rows = [[name, fmt_time(median(v))] for name, v in t.items()]
    text = table(["env (gym.make, default settings, random actions)", "median step"], rows)
    text += "\n\n" + table(
        ["ratio", "value", "target", "verdict"],
        [["SoftPVTOL-v0 / Pendulum-v1", f"{r_pend:.2f}x", "<= 2.0x (aim <= 1.0x)", verdict(r_pend <= 2.0)],
         ["SoftPVTOL-v0 / Acrobot-v1 (RK4 too)", f"{r_acro:.2f}x", "-", "n/a"]])
    for env in envs.values():
        env.close()
    return {
        "title": "1. Single-env step latency",
        "text": text,
        "seconds_per_step": {k: median(v) for k, v in t.items()},
        "ratio_vs_pendulum": r_pend,
        "ratio_vs_acrobot": r_acro,
        "targets": {"ratio_vs_pendulum": {"value": r_pend, "target": "<= 2.0", "pass": r_pend <= 2.0,
                                          "aim": "<= 1.0", "aim_met": r_pend <= 1.0}},
    }


# ----------------------------------------------------------------------------- 2. vector env
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
    checks = [
        ["N = 4096 throughput", fmt_rate(r4096["softpvtol"]), ">= 3 M/s on 2 cores",
         verdict(r4096["softpvtol"] >= 3e6)],
        ["N = 4096 / CartPoleVectorEnv", f"{r4096['ratio_vs_cartpole']:.2f}x", ">= 0.2x",
         verdict(r4096["ratio_vs_cartpole"] >= 0.2)],
        ["N = 256 / sync vector env", f"{r256['ratio_vs_sync']:.0f}x", ">= 50x", verdict(r256["ratio_vs_sync"] >= 50)],
    ]
    text += "\n\n" + table(["target", "value", "target", "verdict"], checks)
    return {
        "title": "2. Vector-env throughput (env-steps/s, random actions, default settings)",
        "text": text,
        "by_num_envs": {str(k): v for k, v in results.items()},
        "targets": {
            "steps_per_second_4096": {"value": r4096["softpvtol"], "target": ">= 3e6",
                                      "pass": r4096["softpvtol"] >= 3e6},
            "ratio_vs_cartpole_4096": {"value": r4096["ratio_vs_cartpole"], "target": ">= 0.2",
                                       "pass": r4096["ratio_vs_cartpole"] >= 0.2},
            "ratio_vs_sync_256": {"value": r256["ratio_vs_sync"], "target": ">= 50",
                                  "pass": r256["ratio_vs_sync"] >= 50},
        },
    }


# -------------------------------------------------------------------- 3. controller + allocation
def _calls_timer(fn, n_calls: int):
    def run() -> float:
        t0 = time.perf_counter()
        for _ in range(n_calls):
            fn()
        return (time.perf_counter() - t0) / n_calls

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
        obs = res.reset(seed=0)[0]
        pol = PassivityPolicy.from_env(act)  # actuators: the controller's allocated actuators
        pol.predict(obs)
        ctrl = PassivityController.from_loop("exact")  # the residual mode's base controller
        sim = res.sim
        args = [x.copy() for x in (sim.qm, sim.qdm, sim.qr, sim.qdr, sim.qddr)]
        if n == 1:
            args = [x[0] for x in args]  # single state (5,) arrays
            obs_p = obs[0]
        else:
            obs_p = obs
        ctrl(*args)
        if n == 1:  # the single env through gym.make, as item 1
            single = {m: gym.make("SoftPVTOL-v0", action_mode=m) for m in ("actuators", "residual")}
            for e in single.values():
                e.reset(seed=0)
            # loop variables bound as defaults (ruff B023); the timed calls are unchanged
            step_act = _calls_timer(lambda s=single, a=a_act: s["actuators"].step(a[0]), calls)
            step_res = _calls_timer(lambda s=single, a=a_res: s["residual"].step(a[0]), calls)
        else:
            step_act = _calls_timer(lambda e=act, a=a_act: e.step(a), calls)
            step_res = _calls_timer(lambda e=res, a=a_res: e.step(a), calls)
        cases = {
            "env step (actuators)": step_act,
            "env step (residual)": step_res,
            "PassivityPolicy.predict": _calls_timer(lambda p=pol, o=obs_p: p.predict(o), calls),
            "PassivityController()": _calls_timer(lambda c=ctrl, a=args: c(*a), calls),
        }
        for fn in cases.values():
            fn()
        t = interleaved(cases, reps)
        base = t["env step (actuators)"]
        extra = [r - a for r, a in zip(t["env step (residual)"], base)]
        entry = {k: median(v) for k, v in t.items()}
        entry["residual_extra"] = median(extra)
        entry["ratio_residual_extra"] = median([e / b for e, b in zip(extra, base)])
        entry["ratio_policy"] = ratios(t["PassivityPolicy.predict"], base)
        entry["ratio_controller"] = ratios(t["PassivityController()"], base)
        results[label] = entry
        per = n
        for name, key in (("residual mode: extra cost of its base controller per step", "ratio_residual_extra"),
                          ("PassivityPolicy.predict", "ratio_policy"),
                          ("PassivityController call", "ratio_controller")):
            value = entry["residual_extra"] if key == "ratio_residual_extra" else entry[
                "PassivityPolicy.predict" if key == "ratio_policy" else "PassivityController()"]
            rows.append([f"{label} (N = {n})", name, fmt_time(value / per) + (" per env" if n > 1 else ""),
                         f"{entry[key]:.2f}x", "<= 1.0x", verdict(entry[key] <= 1.0)])
        rows.append([f"{label} (N = {n})", "one env step (actuators mode), the unit",
                     fmt_time(entry["env step (actuators)"] / per) + (" per env" if n > 1 else ""), "1.00x", "-", "-"])
    text = table(["case", "controller + allocation", "time", "ratio to one env step", "target", "verdict"], rows)
    targets = {}
    for label, entry in results.items():
        for key in ("ratio_residual_extra", "ratio_policy", "ratio_controller"):
            targets[f"{label}_{key}"] = {"value": entry[key], "target": "<= 1.0", "pass": entry[key] <= 1.0}
    return {"title": "3. Passivity controller + allocation per step vs one env step", "text": text,
            "results": results, "targets": targets}


# --------------------------------------------------------------------------------------- 4. PPO
def bench_ppo(quick: bool) -> dict:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from softpvtol_gym.baselines.config.hyperparams import algo_kwargs, load_hyperparams, normalize_kwargs
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    hp = load_hyperparams("ppo", "residual")
    n_envs = int(hp["n_envs"])
    rollout = n_envs * int(hp["n_steps"])
    total = rollout if quick else 5 * rollout
    torch.set_num_threads(1)
    env = SoftPVTOLSB3VecEnv(num_envs=n_envs, action_mode="residual", task="hover", tier="nominal")
    env.seed(0)
    inside = {"seconds": 0.0, "calls": 0}
    step_wait = env.step_wait

    def timed_step_wait():
        t0 = time.perf_counter()
        out = step_wait()
        inside["seconds"] += time.perf_counter() - t0
        inside["calls"] += 1
        return out

    env.step_wait = timed_step_wait
    norm = normalize_kwargs(hp)
    venv = VecNormalize(env, **norm) if norm is not None else env
    model = PPO(hp.get("policy", "MlpPolicy"), venv, seed=0, device="cpu", verbose=0, **algo_kwargs(hp))
    t0 = time.perf_counter()
    model.learn(total_timesteps=total)
    wall = time.perf_counter() - t0
    steps = int(model.num_timesteps)
    share = inside["seconds"] / wall
    per_step = inside["seconds"] / max(1, inside["calls"])
    rows = [
        ["training env-steps/s (rollouts + updates)", fmt_rate(steps / wall), "-", "n/a"],
        ["time in env.step (SB3 VecEnv step_wait of the adapter)", f"{100 * share:.1f} % of wall time", "<= 10 %",
         verdict(share <= 0.10)],
        [f"one batched env step ({n_envs} envs, residual mode)", fmt_time(per_step), "-", "n/a"],
    ]
    text = (f"PPO, residual mode, hover, nominal tier: baselines/hyperparams/ppo.yml (n_envs={n_envs}, "
            f"n_steps={hp['n_steps']}, batch_size={hp['batch_size']}, n_epochs={hp['n_epochs']}, VecNormalize), "
            f"torch.set_num_threads(1), {steps} env-steps, no callbacks.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    venv.close()
    return {"title": "4. PPO training (default train.py configuration)", "text": text,
            "env_steps": steps, "wall_seconds": wall, "env_steps_per_second": steps / wall,
            "env_seconds": inside["seconds"], "env_share": share, "env_step_seconds": per_step,
            "targets": {"env_share": {"value": share, "target": "<= 0.10", "pass": share <= 0.10}}}


# -------------------------------------------------------------------------------- 5. cold start
_COLD_SCRIPT = r"""
import json, os, sys, time
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
t0 = time.perf_counter()
import softpvtol_gym
t1 = time.perf_counter()
import gymnasium as gym
import numpy as np
env = gym.make("SoftPVTOL-v0")
env.reset(seed=0)
env.step(env.action_space.sample())
t2 = time.perf_counter()
out = {"import": t1 - t0, "first_step": t2 - t1}
if "--all" in sys.argv:
    env = gym.make("SoftPVTOL-v0", action_mode="residual")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    t3 = time.perf_counter()
    v = softpvtol_gym.SoftPVTOLVectorEnv(num_envs=1024)
    v.reset(seed=0)
    v.step(np.zeros((1024, 4), np.float32))
    t4 = time.perf_counter()
    out.update(residual_first_step=t3 - t2, vector_first_step=t4 - t3)
print(json.dumps(out))
"""


def _fresh_process(extra_env: dict | None = None, args: tuple = ()) -> dict:
    env = dict(os.environ, **(extra_env or {}))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _COLD_SCRIPT, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, check=True)
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["process"] = time.perf_counter() - t0
    return out


def bench_cold_start(quick: bool) -> dict:
    reps = 2 if quick else 5
    _fresh_process()  # make sure the cache is warm
    runs = [_fresh_process() for _ in range(reps)]
    imp = median([r["import"] for r in runs])
    first = median([r["first_step"] for r in runs])
    proc = median([r["process"] for r in runs])
    rows = [
        ["import softpvtol_gym", fmt_time(imp), "-", "n/a"],
        ["first gym.make + reset + step", fmt_time(first), "-", "n/a"],
        ["import + first step", fmt_time(imp + first), "< 2 s (aim)", verdict(imp + first < 2.0)],
        ["whole fresh process (python start to exit)", fmt_time(proc), "-", "n/a"],
    ]
    result = {"import_seconds": imp, "first_step_seconds": first, "process_seconds": proc}
    if quick:
        rows.append(["cold numba cache: compile for the first step", "skipped (--quick)", "report", "n/a"])
    else:
        with tempfile.TemporaryDirectory() as cache:
            cold = _fresh_process({"NUMBA_CACHE_DIR": cache}, ("--all",))
        result["cold_cache"] = cold
        rows += [
            ["cold numba cache: import + first step (compiles)", fmt_time(cold["import"] + cold["first_step"]),
             "report", "n/a"],
            ["cold numba cache: then first residual-mode step", fmt_time(cold["residual_first_step"]), "report", "n/a"],
            ["cold numba cache: then first vector step (N = 1024)", fmt_time(cold["vector_first_step"]), "report",
             "n/a"],
        ]
    text = ("Fresh `python` subprocesses; numba's cache warm (compiled kernels loaded from `__pycache__`) "
            "unless said otherwise; medians.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    ok = imp + first < 2.0
    result.update(title="5. Cold start", text=text,
                  targets={"import_plus_first_step": {"value": imp + first, "target": "< 2 s", "pass": ok}})
    return result


# ------------------------------------------------------------------------------- 6. time to beat
TIME_TO_BEAT_GOAL = 30.0      # seconds from the start of `python train.py` to the first evaluation above passivity
TRAIN_TOTAL_GOAL = 180.0      # seconds of the whole default `python train.py` (training + final evaluation)


def time_to_beat(evaluations: list[dict], passivity_return: float, launched: float) -> dict | None:
    """The first periodic evaluation whose held-out mean return is above the passivity controller's, with
    its wall-clock seconds since ``launched`` (the epoch time at which train.py was started); None if none."""
    for e in evaluations:
        if e["mean_return"] > passivity_return:
            return {"step": e["step"], "seconds": e["wall_time"] - launched, "mean_return": e["mean_return"],
                    "mean_rms_position_error": e["mean_rms_position_error"]}
    return None


def plot_learning_curve(result: dict, path: Path) -> None:
    """Held-out mean return and RMS position error vs wall-clock seconds since train.py started, with the
    passivity controller's values on the same episodes as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softpvtol_gym.baselines.util.atomic import atomic_path

    curve, pas = result["curve"], result["passivity"]
    t = [e["seconds"] for e in curve]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, label in ((axes[0], "mean_return", "held-out mean return"),
                           (axes[1], "mean_rms_position_error", "held-out mean RMS position error [m]")):
        ax.plot(t, [e[key] for e in curve], "o-", ms=3, label="PPO (periodic evaluation)")
        ax.axhline(pas[key], color="k", ls="--", lw=1, label="passivity controller")
        beat = result["beat"]
        if beat is not None:
            ax.axvline(beat["seconds"], color="tab:green", ls=":", lw=1,
                       label=f"first above passivity: {beat['seconds']:.1f} s")
        ax.axvline(result["total_seconds"], color="tab:gray", ls=":", lw=1,
                   label=f"train.py done: {result['total_seconds']:.0f} s")
        ax.set_xlim(left=0)
        ax.set_xlabel("wall-clock seconds since `python train.py` started")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylim(bottom=max(min(e["mean_return"] for e in curve) - 20, 0))
    fig.suptitle(f"python train.py ({result['description']}); load average {result['loadavg_start'][0]:.2f} at "
                 f"the start, {os.cpu_count()} cores", fontsize=9)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)


def bench_time_to_beat(quick: bool, out: Path | None = None) -> dict:
    """`python train.py` (the default agent) in a fresh process, warm numba cache: the wall-clock seconds from
    its start until its periodic held-out evaluation first beats the passivity controller (mean return on
    the same 10 held-out hover episodes), and of the whole run. --quick: a short run (not the default)."""
    from softpvtol_gym.baselines.config.hyperparams import load_hyperparams

    _fresh_process()  # the numba cache warm, as for item 5
    hp = load_hyperparams("ppo", "residual")
    args = ["--no-progress-bar"]
    if quick:
        args += ["--timesteps", str(2 * int(hp["n_envs"]) * int(hp["n_steps"]))]
    with tempfile.TemporaryDirectory(prefix="softpvtol-bench-train-") as tmp:
        run_dir = Path(tmp) / "run"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
        load_start = list(os.getloadavg())
        launched = time.time()
        proc = subprocess.run([sys.executable, str(ROOT / "train.py"), *args, "--out", str(run_dir)], cwd=tmp,
                              env=env, capture_output=True, text=True)
        total = time.time() - launched
        load_end = list(os.getloadavg())
        if proc.returncode != 0:
            raise RuntimeError(f"train.py failed ({proc.returncode}): {proc.stderr[-2000:]}")
        evaluations = json.loads((run_dir / "evaluations.json").read_text())
        report = json.loads((run_dir / "result.json").read_text())
    pas = report["passivity"]["summary"]
    learned = report["ppo"]["summary"]
    beat = time_to_beat(evaluations, pas["mean_return"], launched)
    cfg = report["config"]
    description = (f"PPO, residual mode, hover, nominal; {cfg['timesteps']:,} steps, {cfg['n_envs']} envs x "
                   f"{cfg['hyperparams']['n_steps']} steps, batch {cfg['hyperparams']['batch_size']}, "
                   f"{cfg['hyperparams']['n_epochs']} epochs")
    curve = [{"step": e["step"], "seconds": e["wall_time"] - launched, "mean_return": e["mean_return"],
              "mean_rms_position_error": e["mean_rms_position_error"]} for e in evaluations]
    result = {
        "title": "6. Time to beat the passivity controller (`python train.py`, fresh process)",
        "command": "python train.py" + (" " + " ".join(args) if args else ""),
        "description": description, "beat": beat, "total_seconds": total, "train_seconds": report["train_seconds"],
        "curve": curve, "passivity": {k: pas[k] for k in ("mean_return", "mean_rms_position_error")},
        "final": {k: learned[k] for k in ("mean_return", "mean_rms_position_error", "crash_rate")},
        "loadavg_start": load_start, "loadavg_end": load_end,
        # what train.py printed (the README shows it: a test checks that the README's block matches)
        "stdout": proc.stdout.replace(str(run_dir), "<run dir>"),
    }
    beat_ok = beat is not None and beat["seconds"] <= TIME_TO_BEAT_GOAL
    rows = [
        ["first periodic evaluation above passivity (mean return, 10 held-out episodes)",
         "never" if beat is None else f"{beat['seconds']:.1f} s ({beat['step']:,} steps; {beat['mean_return']:.1f} vs "
         f"{pas['mean_return']:.1f}, RMS position error {beat['mean_rms_position_error']:.3f} m vs "
         f"{pas['mean_rms_position_error']:.3f} m)", f"<= {TIME_TO_BEAT_GOAL:.0f} s", verdict(beat_ok)],
        ["whole run (training + final evaluation)", f"{total:.1f} s (training {report['train_seconds']:.1f} s)",
         f"<= {TRAIN_TOTAL_GOAL:.0f} s", verdict(total <= TRAIN_TOTAL_GOAL)],
        ["final evaluation: PPO vs passivity (return, RMS position error)",
         f"{learned['mean_return']:.1f} / {learned['mean_rms_position_error']:.3f} m vs {pas['mean_return']:.1f} / "
         f"{pas['mean_rms_position_error']:.3f} m", "-", "n/a"],
        ["load average (1 min) at the start / end", f"{load_start[0]:.2f} / {load_end[0]:.2f}", "-", "n/a"],
    ]
    text = (f"`{result['command']}` ({description}) in a fresh process, warm numba cache; seconds from its "
            f"start (wall clock). The periodic evaluation (every `--eval-freq` steps, 10 held-out episodes) is "
            f"part of the timed run.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    if out is not None:
        plot_learning_curve(result, out / "time_to_beat.png")
        text += "\n\n![learning curve](time_to_beat.png)"
    result["text"] = text
    result["targets"] = {
        "seconds_to_beat": {"value": float("nan") if beat is None else beat["seconds"],
                            "target": f"<= {TIME_TO_BEAT_GOAL:.0f}", "pass": beat_ok},
        "train_total_seconds": {"value": total, "target": f"<= {TRAIN_TOTAL_GOAL:.0f}",
                                "pass": total <= TRAIN_TOTAL_GOAL},
    }
    return result


# ------------------------------------------------------------------------------------- driver
BENCHES = {"single": bench_single, "vector": bench_vector, "controller": bench_controller, "ppo": bench_ppo,
           "cold_start": bench_cold_start, "time_to_beat": bench_time_to_beat}


# ------------------------------------------------------------------------------- README table
README = ROOT / "docs" / "performance.md"  # the page with the generated Performance table
README_START = "<!-- benchmarks/run.py: table start (generated from benchmarks/results.json, do not edit) -->"
README_END = "<!-- benchmarks/run.py: table end -->"


def readme_table(payload: dict) -> str:
    """The README's Performance table from a full run's results.json payload."""
    it = payload["items"]
    tg = {name: {k: t["value"] for k, t in res["targets"].items()} for name, res in it.items()}
    ctl = tg["controller"]
    cold = it["cold_start"]
    ppo = it["ppo"]
    ttb = it["time_to_beat"]
    beat = ttb["beat"]
    rows = [
        ["1. single env step (`gym.make(\"SoftPVTOL-v0\")`, random actions) / `Pendulum-v1`",
         f"{tg['single']['ratio_vs_pendulum']:.2f}x (Acrobot-v1: {it['single']['ratio_vs_acrobot']:.2f}x)",
         "<= 2.0x, aim <= 1.0x"],
        ["2. vector env, N = 4096, random actions",
         f"{tg['vector']['steps_per_second_4096'] / 1e6:.2f} M env-steps/s, "
         f"{tg['vector']['ratio_vs_cartpole_4096']:.2f}x `CartPoleVectorEnv`", ">= 3 M/s, >= 0.2x"],
        ["2. vector env / `make_vec(..., \"sync\")`, N = 256", f"{tg['vector']['ratio_vs_sync_256']:.0f}x", ">= 50x"],
        ["3. controller + allocation / one env step, single: residual mode, `PassivityPolicy.predict`, "
         "`PassivityController()`",
         ", ".join(f"{ctl['single_' + k]:.2f}x" for k in ("ratio_residual_extra", "ratio_policy", "ratio_controller")),
         "<= 1x"],
        ["3. the same, batched (N = 4096, per env)",
         ", ".join(f"{ctl['batched_' + k]:.2f}x" for k in ("ratio_residual_extra", "ratio_policy", "ratio_controller")),
         "<= 1x"],
        ["4. PPO (default `train.py` configuration): share of wall time in `env.step` (training env-steps/s)",
         f"{100 * ppo['env_share']:.1f} % ({ppo['env_steps_per_second'] / 1e3:.1f} k env-steps/s)", "<= 10 %"],
        ["5. `import softpvtol_gym` + first reset and step, fresh process",
         f"{tg['cold_start']['import_plus_first_step']:.2f} s (cold numba cache: "
         f"{cold['cold_cache']['process']:.1f} s in all)", "< 2 s"],
        ["6. `python train.py`: from its start to the first periodic held-out evaluation above the passivity "
         "controller; the whole run ([learning curve](benchmarks/time_to_beat.png))",
         f"{tg['time_to_beat']['seconds_to_beat']:.1f} s ({beat['step']:,} steps); "
         f"{tg['time_to_beat']['train_total_seconds']:.0f} s (load average {ttb['loadavg_start'][0]:.2f})"
         if beat is not None else f"never; {tg['time_to_beat']['train_total_seconds']:.0f} s",
         f"<= {TIME_TO_BEAT_GOAL:.0f} s; <= {TRAIN_TOTAL_GOAL:.0f} s"],
    ]
    m = payload["machine"]
    head = (f"From `{payload['command']}` at commit `{m['commit'][:7]}`, {payload['date']}, {m['cores']} cores, "
            f"load average {m['loadavg_start'][0]:.2f} at the start.")
    return "\n".join([head, "", table(["item", "measured", "target"], rows)])


def update_readme(payload: dict, path: Path = README) -> bool:
    """Replace the README's generated table; False if its markers are missing."""
    text = path.read_text()
    if README_START not in text or README_END not in text:
        return False
    a = text.index(README_START) + len(README_START)
    b = text.index(README_END)
    atomic_write_text(path, text[:a] + "\n" + readme_table(payload) + "\n" + text[b:])
    return True


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few repetitions (a smoke test, ~20 s)")
    parser.add_argument("--only", nargs="+", choices=ITEMS, help="run only these items")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks", help="folder for RESULTS.md and results.json")
    args = parser.parse_args(argv)
    items = args.only or list(ITEMS)
    command = "python benchmarks/run.py" + (" --quick" if args.quick else "") + (
        " --only " + " ".join(items) if args.only else "")
    facts = machine_facts()
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    results = {}
    for name in items:
        t0 = time.perf_counter()
        res = BENCHES[name](args.quick, args.out) if name == "time_to_beat" else BENCHES[name](args.quick)
        res["benchmark_seconds"] = time.perf_counter() - t0
        results[name] = res
        print(f"\n## {res['title']}\n\n{res['text']}\n", flush=True)
    facts["loadavg_end"] = list(os.getloadavg())
    summary = [[f"{name}: {key}", f"{t['value']:.3g}", t["target"], verdict(t["pass"])]
               for name, res in results.items() for key, t in res["targets"].items()]
    md = [
        "# Benchmark results",
        "",
        "Generated by `benchmarks/run.py`; do not edit by hand, rerun the command.",
        "",
        f"- command: `{command}`",
        f"- commit: `{facts['commit']}`",
        f"- date: {date}",
        f"- machine: {facts['cores']} cores ({facts['cpu']}), {facts['platform']}; "
        f"load average (1, 5, 15 min) {', '.join(f'{x:.2f}' for x in facts['loadavg_start'])} at the start, "
        f"{', '.join(f'{x:.2f}' for x in facts['loadavg_end'])} at the end",
        f"- versions: python {facts['python']}, numpy {facts['numpy']}, numba {facts['numba']}, "
        f"gymnasium {facts['gymnasium']}, torch {facts['torch']}, stable-baselines3 {facts['stable_baselines3']}, "
        f"softpvtol-gym {facts['softpvtol_gym']}",
        f"- threads for large batches: {facts['numba_num_threads']} (NUMBA_NUM_THREADS)",
        "",
        "Ratios are medians over interleaved repetitions measured in the same process (absolute times on a "
        "shared machine are noisy).",
        "",
        "## Summary",
        "",
        table(["item: measure", "value", "target", "verdict"], summary),
        "",
    ]
    for res in results.values():
        md += [f"## {res['title']}", "", res["text"], ""]
    atomic_write_text(args.out / "RESULTS.md", "\n".join(md))
    payload = {"command": command, "date": date, "quick": args.quick, "machine": facts,
               "items": {k: {kk: vv for kk, vv in v.items() if kk != "text"} for k, v in results.items()}}
    atomic_write_text(args.out / "results.json", json.dumps(payload, indent=2, default=float) + "\n")
    print(f"wrote {args.out / 'RESULTS.md'} and {args.out / 'results.json'}")
    if not args.quick and not args.only and args.out.resolve() == (ROOT / "benchmarks").resolve():
        if update_readme(json.loads((args.out / "results.json").read_text())):
            print(f"updated the Performance table in {README}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
