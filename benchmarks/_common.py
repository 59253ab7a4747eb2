"""Shared by the benchmark items: medians of interleaved repetitions, formatting, Markdown tables and
the machine's facts (benchmarks/run.py runs the items)."""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
from pathlib import Path

import gymnasium as gym
import numpy as np

import softpvtol_gym

ROOT = Path(__file__).resolve().parent.parent


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
        "commit": commit + (" (with uncommitted changes to softpvtol_gym/ or benchmarks/*.py)" if dirty else ""),
        "loadavg_start": list(os.getloadavg()),
    }
