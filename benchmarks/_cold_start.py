"""Item 5: import and first step in fresh processes, with a warm and a cold numba cache, and what a cold
start says while it compiles (benchmarks/run.py)."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time

from benchmarks._common import ROOT, fmt_time, median, table, verdict

#: the targets, cold numba cache, in CPU seconds of a fresh process: to its first step (import included), and the
#: README's quickstart (``PassivityPolicy`` on track_paper) as a whole process
COLD_ACTUATORS_TARGET = 20.0
COLD_RESIDUAL_TARGET = 30.0
COLD_QUICKSTART_TARGET = 30.0
#: the longest a cold start may stay silent (stderr) while it compiles
SILENCE_TARGET = 10.0

_COLD_SCRIPT = r"""
import json, os, sys, time
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
t0 = time.perf_counter()
import softpvtol_gym
t1 = time.perf_counter()
import gymnasium as gym
import numpy as np
mode = sys.argv[1]
env = gym.make("SoftPVTOL-v0", action_mode=mode)
env.reset(seed=0)
env.step(env.action_space.sample())
t2 = time.perf_counter()
out = {"import": t1 - t0, "first_step": t2 - t1, "cpu_to_first_step": time.process_time()}
if "--vector" in sys.argv:
    v = softpvtol_gym.SoftPVTOLVectorEnv(num_envs=1024, action_mode=mode)
    v.reset(seed=0)
    v.step(np.zeros((1024, v.single_action_space.shape[0]), np.float32))
    out["vector_first_step"] = time.perf_counter() - t2
print(json.dumps(out))
"""


def _watched(cmd: list[str], env: dict) -> tuple[str, list[tuple[float, str]], float, float]:
    """Run cmd; (stdout, stderr lines with the seconds since the start, total seconds, CPU seconds of the process:
    user + system, its own children included)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[tuple[float, str]] = []

    def read() -> None:
        for line in proc.stderr:
            lines.append((time.perf_counter() - t0, line.rstrip("\n")))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    out = proc.stdout.read()
    cpu = _wait_cpu_seconds(proc)
    reader.join()
    if proc.returncode:
        raise RuntimeError(f"{cmd} failed ({proc.returncode}): {[ln for _, ln in lines][-5:]}")
    return out, lines, time.perf_counter() - t0, cpu


def _wait_cpu_seconds(proc: subprocess.Popen) -> float:
    """Wait for ``proc``; its CPU seconds (user + system; the children it waited for included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc.wait()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def compile_report(lines: list[tuple[float, str]], total: float) -> dict:
    """The compile announcements of a cold process: starts, ends (each start has its end) and the longest
    silence on stderr (from the start, between lines, to the exit)."""
    text = [ln for _, ln in lines]
    starts = [ln for ln in text if ln.startswith("softpvtol_gym: compiling ") and "first run only" not in ln]
    ends = [ln for ln in text if ln.startswith("softpvtol_gym: compiled ")]
    times = [0.0] + [t for t, _ in lines] + [total]
    silence = max(b - a for a, b in zip(times, times[1:]))
    return {"compiles": len(starts), "ends": len(ends), "announced": len(starts) == len(ends) and bool(starts),
            "longest_silence": silence}


def _fresh_process(extra_env: dict | None = None, args: tuple = ("actuators",)) -> dict:
    env = dict(os.environ, **(extra_env or {}))
    out, lines, total, cpu = _watched([sys.executable, "-c", _COLD_SCRIPT, *args], env)
    res = json.loads(out.strip().splitlines()[-1])
    res["process"] = total
    res["process_cpu"] = cpu
    res.update(compile_report(lines, total))
    return res


def _cold(args: tuple) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        return _fresh_process({"SOFTPVTOL_GYM_CACHE_DIR": cache}, args)


def readme_quickstart() -> str:
    """The README's quickstart: the first ``python`` block under its "## Quickstart" heading."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("\n## Quickstart"):]
    start = section.index("```python\n") + len("```python\n")
    return section[start:section.index("\n```", start)]


def cold_quickstart() -> dict:
    """The README's quickstart in a fresh process with a cold cache: its wall and CPU seconds."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, SOFTPVTOL_GYM_CACHE_DIR=cache)
        out, lines, total, cpu = _watched([sys.executable, "-c", readme_quickstart()], env)
    return {"seconds": total, "cpu_seconds": cpu, "output": out.strip(), **compile_report(lines, total)}


def cold_train(timeout: float = 900.0) -> dict:
    """``python train.py`` (a short run) with a cold cache: its seconds and its longest silence on stderr
    and stdout together."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, SOFTPVTOL_GYM_CACHE_DIR=os.path.join(tmp, "cache"), PYTHONUNBUFFERED="1")
        cmd = [sys.executable, "train.py", "--timesteps", "4096", "--eval-episodes", "2", "--no-progress-bar",
               "--out", os.path.join(tmp, "run")]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        stamps = [0.0]
        for _ in proc.stdout:
            stamps.append(time.perf_counter() - t0)
        proc.wait(timeout=timeout)
        total = time.perf_counter() - t0
        stamps.append(total)
    return {"seconds": total, "longest_silence": max(b - a for a, b in zip(stamps, stamps[1:])),
            "returncode": proc.returncode}


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
    targets = {"import_plus_first_step": {"value": imp + first, "target": "< 2 s", "pass": imp + first < 2.0}}
    if quick:
        rows.append(["cold numba cache: compiles", "skipped (--quick)", "-", "n/a"])
    else:
        act = _cold(("actuators", "--vector"))
        res = _cold(("residual",))
        quick_start = cold_quickstart()
        train = cold_train()
        result.update(cold_actuators=act, cold_residual=res, cold_quickstart=quick_start, cold_train=train)
        t_act, t_res = act["import"] + act["first_step"], res["import"] + res["first_step"]
        c_act, c_res, c_qs = act["cpu_to_first_step"], res["cpu_to_first_step"], quick_start["cpu_seconds"]
        silence = max(act["longest_silence"], res["longest_silence"])
        announced = act["announced"] and res["announced"]
        rows += [
            ["cold cache: import + first step, actuators mode (CPU; wall)", f"{c_act:.1f} CPU s; {fmt_time(t_act)}",
             f"<= {COLD_ACTUATORS_TARGET:.0f} CPU s", verdict(c_act <= COLD_ACTUATORS_TARGET)],
            ["cold cache: import + first step, residual mode, a process of its own (CPU; wall)",
             f"{c_res:.1f} CPU s; {fmt_time(t_res)}", f"<= {COLD_RESIDUAL_TARGET:.0f} CPU s",
             verdict(c_res <= COLD_RESIDUAL_TARGET)],
            ["cold cache: the README's quickstart, a whole process (CPU; wall)",
             f"{c_qs:.1f} CPU s; {fmt_time(quick_start['seconds'])}", f"<= {COLD_QUICKSTART_TARGET:.0f} CPU s",
             verdict(c_qs <= COLD_QUICKSTART_TARGET)],
            ["cold cache: then a first vector step (N = 1024, actuators)", fmt_time(act["vector_first_step"]),
             "report", "n/a"],
            ["compiles announced on stderr (start and end lines)",
             f"{act['compiles']} + {res['compiles']} compiles, {act['ends']} + {res['ends']} ends",
             "every one", verdict(announced)],
            ["longest silence of those cold processes (stderr)", fmt_time(silence), f"<= {SILENCE_TARGET:.0f} s",
             verdict(silence <= SILENCE_TARGET)],
            ["cold cache: `python train.py --timesteps 4096 --eval-episodes 2`, longest silence (stdout + stderr)",
             f"{fmt_time(train['longest_silence'])} (run {fmt_time(train['seconds'])})", f"<= {SILENCE_TARGET:.0f} s",
             verdict(train["longest_silence"] <= SILENCE_TARGET and train["returncode"] == 0)],
        ]
        targets.update(
            cold_actuators_first_step_cpu={"value": c_act, "target": f"<= {COLD_ACTUATORS_TARGET:.0f} CPU s",
                                           "pass": c_act <= COLD_ACTUATORS_TARGET},
            cold_residual_first_step_cpu={"value": c_res, "target": f"<= {COLD_RESIDUAL_TARGET:.0f} CPU s",
                                          "pass": c_res <= COLD_RESIDUAL_TARGET},
            cold_quickstart_cpu={"value": c_qs, "target": f"<= {COLD_QUICKSTART_TARGET:.0f} CPU s",
                                 "pass": c_qs <= COLD_QUICKSTART_TARGET},
            compiles_announced={"value": float(announced), "target": "every compile", "pass": announced},
            longest_silence={"value": max(silence, train["longest_silence"]), "target": f"<= {SILENCE_TARGET:.0f} s",
                             "pass": max(silence, train["longest_silence"]) <= SILENCE_TARGET
                             and train["returncode"] == 0},
        )
    text = ("Fresh `python` subprocesses; numba's cache warm (compiled kernels loaded from the cache) unless said "
            "otherwise (a cold cache: an empty `SOFTPVTOL_GYM_CACHE_DIR`); medians of the warm runs, one run of "
            "each cold case.\n\n")
    text += table(["measure", "value", "target", "verdict"], rows)
    result.update(title="5. Cold start", text=text, targets=targets)
    return result
