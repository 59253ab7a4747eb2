"""Trained runs evaluated on both tracking tasks and three tiers (the tracking evaluation).

    python benchmarks/tracking_evaluation.py --runs-dir RUNS \
        --out benchmarks/tracking_evaluation.json --table benchmarks/TRACKING_EVALUATION.md --docs benchmarks/STUDIES.md

Every run directory under ``--runs-dir`` (a finished ``train.py`` run) is loaded with
:meth:`softpvtol_gym.baselines.training.policy.LearnedPolicy.load` and evaluated with
:func:`softpvtol_gym.baselines.evaluation.run_episodes`
on ``track_paper`` and ``track_random``, tiers ``nominal``, ``mismatch`` and ``hard``: 20 episodes each,
evaluation seed 1,000,000 (the same episodes for every run), with the env arguments the run trained with
(``config.eval_env_kwargs()``: its base loop and env options; its frame stack comes from its config). The
passivity controller of the residual mode's base loop (``bounded``, the residual action 0) is evaluated
on the same episodes as the reference. Per run and cell the JSON holds the mean, median and IQM RMS
position error, the crash rate, the mean control effort, and the per-episode RMS position errors; the
table's last part pools the episodes of a run's seeds (IQM over seeds x episodes, the leaderboard's
estimate). A run already
in ``--out`` is not evaluated again (``--again`` re-evaluates every run). ``--table`` writes the Markdown
tables generated from the JSON (never edit them by hand); ``--docs benchmarks/STUDIES.md`` replaces the summary table
between its markers in "Tracking: what was tried".
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402

TASKS = ("track_paper", "track_random")
TIERS = ("nominal", "mismatch", "hard")
EPISODES = 20
EVAL_SEED = 1_000_000
REFERENCE = "passivity-bounded"
DOCS_START = ("<!-- benchmarks/tracking_evaluation.py summary table: start (generated from "
              "benchmarks/tracking_evaluation.json, do not edit) -->")
DOCS_END = "<!-- benchmarks/tracking_evaluation.py summary table: end -->"
SEED_SUFFIX = re.compile(r"_s(\d+)$")


def iqm(values) -> float:
    """The interquartile mean (the leaderboard's point estimate: rliable's aggregate_iqm, a 25 % trimmed mean)."""
    from scipy.stats import trim_mean

    return float(trim_mean(np.asarray(values, dtype=float).ravel(), 0.25))


def cell_summary(episodes: list[dict]) -> dict:
    err = np.array([e["rms_position_error"] for e in episodes])
    return {"episodes": len(episodes),
            "mean_rms_position_error": float(err.mean()),
            "median_rms_position_error": float(np.median(err)),
            "iqm_rms_position_error": iqm(err),
            "crash_rate": float(np.mean([e["crashed"] for e in episodes])),
            "mean_control_effort": float(np.mean([e["control_effort"] for e in episodes])),
            "rms_position_errors": [float(x) for x in err]}


def train_command(config, run_dir: Path) -> str:
    """The train.py command that trains ``config`` (from its recorded overrides and env options)."""
    parts = ["python train.py", f"--action-mode {config.action_mode}", f"--task {config.task}",
             f"--tier {config.tier}", f"--timesteps {config.timesteps}", f"--seed {config.seed}"]
    parts += [f"--hp {o}" for o in config.overrides if not o.startswith(("n_timesteps=", "n_envs="))]
    parts += [f"--env {k}={v}" for k, v in config.env_options.items()]
    parts.append(f"--out {run_dir}")
    return " ".join(parts)


def evaluate_run(run_dir: Path) -> dict:
    from softpvtol_gym.baselines.config.hyperparams import frame_stack
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    policy, config = LearnedPolicy.load(run_dir)
    result = {}
    t0 = time.perf_counter()
    for task in TASKS:
        for tier in TIERS:
            eps = run_episodes(policy, config.action_mode, task, tier, EPISODES, EVAL_SEED,
                               env_kwargs=config.eval_env_kwargs())
            result[f"{task}/{tier}"] = cell_summary(eps)
    train_result = run_dir / "result.json"
    train_seconds = json.loads(train_result.read_text()).get("train_seconds") if train_result.is_file() else None
    return {"run": run_dir.name, "group": SEED_SUFFIX.sub("", run_dir.name), "seed": config.seed,
            "trained_task": config.task, "trained_tier": config.tier, "timesteps": config.timesteps,
            "frame_stack": frame_stack(config.hyperparams), "env_options": dict(config.env_options),
            "controller_loop": config.controller_loop, "train_seconds": train_seconds,
            "command": train_command(config, run_dir), "eval_seconds": round(time.perf_counter() - t0, 1),
            "cells": result}


def evaluate_reference() -> dict:
    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    result = {}
    for task in TASKS:
        for tier in TIERS:
            probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="residual", task=task, tier=tier,
                                       controller_loop="bounded")
            eps = run_episodes(PassivityPolicy.from_env(probe), "residual", task, tier, EPISODES, EVAL_SEED,
                               env_kwargs={"controller_loop": "bounded"})
            result[f"{task}/{tier}"] = cell_summary(eps)
    return {"run": REFERENCE, "group": REFERENCE, "seed": None, "cells": result,
            "command": "PassivityPolicy in the residual mode (residual 0), controller_loop='bounded'"}


def git_commit() -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() or None


def _cell(c: dict) -> str:
    return (f"{c['mean_rms_position_error']:.3f} / {c['median_rms_position_error']:.3f} "
            f"({c['crash_rate']:.2f}, {c['mean_control_effort']:.3f})")


def technique(run: dict) -> str:
    """What a run changed against the residual-mode defaults (its frame stack and env options)."""
    parts = ([f"frame_stack={run['frame_stack']}"] if run["frame_stack"] > 1 else []) + \
        [f"{k}={v}" for k, v in run["env_options"].items()]
    return ", ".join(parts) or "defaults"


def summary_table(data: dict) -> str:
    """One row per technique and training tier (and the reference): the IQM RMS position error [m] over seeds x
    episodes (the leaderboard's estimate) and the mean crash rate, per evaluation task and tier."""
    header = "| technique | trained on | seeds | " + " | ".join(f"{t} {tier}" for t in TASKS for tier in TIERS) + \
        " | command |"
    lines = [header, "|" + "---|" * (4 + len(TASKS) * len(TIERS))]
    groups: dict[tuple, list[dict]] = {}
    for r in sorted(data["runs"], key=lambda r: (r["trained_tier"] != "nominal", r["trained_tier"], technique(r),
                                                  r["timesteps"], r["seed"])):
        groups.setdefault((technique(r), r["trained_tier"], r["timesteps"]), []).append(r)
    rows = [(REFERENCE, "-", "-", [data["reference"]], data["reference"]["command"])]
    for (tech, tier, steps), rs in groups.items():
        cmd = re.sub(r" --out \S+$", "", re.sub(r"--seed \d+", "--seed S", rs[0]["command"]))
        rows.append((tech, f"track_random {tier}, {steps / 1e6:g}M steps", ", ".join(str(r["seed"]) for r in rs), rs,
                     f"`{cmd}`"))
    for tech, trained, seeds, rs, cmd in rows:
        cells = []
        for task in TASKS:
            for tier in TIERS:
                cs = [r["cells"][f"{task}/{tier}"] for r in rs]
                pooled = [x for c in cs for x in c["rms_position_errors"]]
                cells.append(f"{iqm(pooled):.3f} ({np.mean([c['crash_rate'] for c in cs]):.2f})")
        lines.append(f"| {tech} | {trained} | {seeds} | " + " | ".join(cells) + f" | {cmd} |")
    return "\n".join(lines) + "\n"


def markdown(data: dict) -> str:
    lines = ["<!-- generated by python benchmarks/tracking_evaluation.py --table from "
             "benchmarks/tracking_evaluation.json; do not edit by hand -->", "",
             "# Tracking evaluation", "",
             f"Generated by `python benchmarks/tracking_evaluation.py --runs-dir {data['runs_dir']} --out "
             "benchmarks/tracking_evaluation.json --table benchmarks/TRACKING_EVALUATION.md "
             "--docs benchmarks/STUDIES.md` "
             f"(load average {data['loadavg'][0]:.1f} on {data['cpus']} CPUs during the evaluation). Each run is a "
             f"PPO residual-mode policy trained on `track_random` with the command listed under the tables; "
             f"each cell is {EPISODES} held-out episodes (evaluation seed {EVAL_SEED:,}, the same episodes for "
             f"every row), with the run's own env options and frame stack.", "",
             "Cell: mean / median RMS position error [m] (crash rate, mean control effort). "
             f"`{REFERENCE}`: the passivity controller (the residual mode's base loop, residual 0) on the same "
             "episodes.", ""]
    rows = [data["reference"], *sorted(data["runs"], key=lambda r: (r["group"], r["seed"]))]
    for task in TASKS:
        lines += [f"## {task}", "", "| run | seed | " + " | ".join(TIERS) + " |",
                  "|---|---|" + "---|" * len(TIERS)]
        for r in rows:
            seed = "-" if r["seed"] is None else str(r["seed"])
            lines.append(f"| {r['group']} | {seed} | " + " | ".join(_cell(r["cells"][f"{task}/{t}"]) for t in TIERS)
                         + " |")
        lines.append("")
    lines += ["## Pooled over seeds", "", summary_table(data)]
    lines += ["", "## Training commands", ""]
    for r in sorted(data["runs"], key=lambda r: (r["group"], r["seed"])):
        secs = "" if r.get("train_seconds") is None else f" ({r['train_seconds']:.0f} s of training)"
        lines.append(f"- `{r['run']}`: `{r['command']}`{secs}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs-dir", type=Path, help="a folder of finished train.py run directories")
    ap.add_argument("--out", type=Path, required=True, help="the JSON file (runs are added to it)")
    ap.add_argument("--table", type=Path, default=None, help="write the Markdown tables of --out here")
    ap.add_argument("--again", action="store_true", help="evaluate runs already in --out again")
    ap.add_argument("--docs", type=Path, default=None,
                    help="replace the summary table between the markers of this Markdown file (benchmarks/STUDIES.md)")
    args = ap.parse_args(argv)
    import torch

    from softpvtol_gym.baselines.training.loop import torch_threads

    # as in training (SOFTPVTOL_TORCH_THREADS, default 1): torch's default of one thread per core makes each
    # forward pass of the small MLP wait for busy cores on a loaded machine (9 ms instead of 0.2 ms here)
    torch.set_num_threads(torch_threads())
    data = json.loads(args.out.read_text()) if args.out.is_file() else {"runs": [], "reference": None}
    if args.runs_dir is not None:
        data["runs_dir"] = str(args.runs_dir)
        done = {r["run"] for r in data["runs"]} if not args.again else set()
        if args.again:
            data["runs"] = []
        for run_dir in sorted(p for p in args.runs_dir.iterdir() if (p / "checkpoint.json").is_file()):
            if run_dir.name in done:
                continue
            print(f"evaluating {run_dir.name}", file=sys.stderr, flush=True)
            data["runs"].append(evaluate_run(run_dir))
            data.update(commit=git_commit(), loadavg=list(os.getloadavg()), cpus=os.cpu_count())
            atomic_write_text(args.out, json.dumps(data, indent=1))
        if data["reference"] is None or args.again:
            data["reference"] = evaluate_reference()
            data.update(commit=git_commit(), loadavg=list(os.getloadavg()), cpus=os.cpu_count())
            atomic_write_text(args.out, json.dumps(data, indent=1))
    if args.table is not None:
        atomic_write_text(args.table, markdown(data))
    if args.docs is not None:
        text = args.docs.read_text()
        if DOCS_START not in text or DOCS_END not in text:
            raise SystemExit(f"{args.docs} has no summary-table markers ({DOCS_START} ... {DOCS_END})")
        head, rest = text.split(DOCS_START, 1)
        atomic_write_text(args.docs, head + DOCS_START + "\n" + summary_table(data) + rest[rest.index(DOCS_END):])
    return 0


if __name__ == "__main__":
    sys.exit(main())
