"""Item 5: import and first step in fresh processes, with a warm and a cold numba cache (benchmarks/run.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

from benchmarks._common import ROOT, fmt_time, median, table, verdict

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
