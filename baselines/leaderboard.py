"""Build the leaderboard from the job results: statistics (rliable), JSON, LEADERBOARD.md and a chart.

    python baselines/leaderboard.py              # results -> baselines/results/leaderboard.json -> LEADERBOARD.md + PNG
    python baselines/leaderboard.py --from-json  # only re-render LEADERBOARD.md and the PNG from the committed JSON

Inputs: the ``eval.json`` of every job of ``baselines/leaderboard.yml`` under
``baselines/results/leaderboard_runs/`` (``python baselines/run_jobs.py`` makes them).

Statistics (rliable, Agarwal et al. 2021): for each (task, evaluation tier) and each entry (a policy;
for PPO an action mode and the tier it was trained on), the scores form a matrix (runs x episodes):
runs are the PPO training seeds (one row for the deterministic passivity controllers), episodes the
shared, seeded evaluation episodes. Point estimates are the IQM (interquartile mean) of the RMS
position error and of the return, and the mean crash rate; 95 % CIs come from rliable's stratified
bootstrap over runs *and* episodes (``task_bootstrap=True``), so they include both the seed-to-seed
variation of training and the finite evaluation set. The probability of improvement P(X < Y) of an
entry over the best passivity controller is rliable's (Mann-Whitney over runs, averaged over
episodes), on the RMS position error; its CI resamples runs only (rliable's independent-samples
bootstrap for pairs does not support resampling episodes), so for the passivity-vs-passivity row it
is a point. The bootstrap is seeded: the JSON, and
therefore LEADERBOARD.md, are reproducible.

Every output (JSON, Markdown, PNG) is written atomically; the output paths are checked, and the spec or
the JSON validated, before any work. Exit codes: 0 done, 2 bad input (one line, nothing written).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

from baselines.atomic import atomic_path, atomic_write_text
from baselines.cli import Parser, run_main
from baselines.errors import ConfigError
from baselines.jobs import EVAL_FILE, REPO_ROOT, RUNS_DIR, SPEC_FILE, load_jobs, load_spec, read_eval

RESULTS_JSON = Path(__file__).resolve().parent / "results" / "leaderboard.json"
LEADERBOARD_MD = REPO_ROOT / "LEADERBOARD.md"
CHART_PNG = Path(__file__).resolve().parent / "results" / "leaderboard.png"
REFERENCE = "passivity-bounded"   # the strongest analytic loop, the env's default (docs/control.md)
BOOTSTRAP_REPS = 2000
POI_BOOTSTRAP_REPS = 300  # rliable's probability of improvement runs scipy per episode: slow
BOOTSTRAP_SEED = 0
COMMAND = "python baselines/run_jobs.py && python baselines/leaderboard.py"


def entry_label(job: dict) -> str:
    if job["policy"] == "ppo":
        return f"PPO-{job['action_mode']} (trained on {job['train_tier']})"
    return job["policy"]


# ------------------------------------------------------------------------------------ collect
def collect(root: Path = RUNS_DIR, spec: Path = SPEC_FILE) -> tuple[list[dict], list[str]]:
    """Every (job, evaluation tier) as a cell with its per-episode metrics; and the missing job names."""
    cells, missing = [], []
    for job in load_jobs(spec):
        path = job.folder(root) / EVAL_FILE
        if not path.is_file():
            missing.append(job.name)
            continue
        rec = read_eval(path)
        j = rec["job"]
        if (j.get("policy"), j.get("task"), j.get("seed")) != (job.policy, job.task, job.seed):
            raise ConfigError(f"{path} holds the result of another job ({j.get('policy')}, {j.get('task')}, seed "
                              f"{j.get('seed')}); expected {job.name}")
        for tier, episodes in rec["eval"].items():
            cells.append({
                "entry": entry_label(j), "policy": j["policy"], "action_mode": j["action_mode"], "task": j["task"],
                "train_tier": j["train_tier"], "tier": tier, "seed": j["seed"], "checkpoint": rec["checkpoint"],
                "train_seconds": rec["train_seconds"], "eval_seed": j["eval_seed"], "episodes": episodes,
                "summary": _summary(episodes),
            })
    return cells, missing


def _summary(episodes: list[dict]) -> dict:
    from baselines.evaluation import summarize

    return summarize(episodes)


# ----------------------------------------------------------------------------------- statistics
def _matrix(cells: list[dict], key: str, sign: float = 1.0) -> np.ndarray:
    """(runs x episodes) scores of one entry, runs sorted by seed."""
    rows = [[sign * float(e[key]) for e in c["episodes"]] for c in sorted(cells, key=lambda c: c["seed"])]
    return np.asarray(rows, dtype=float)


def _three_metrics(scores: np.ndarray) -> np.ndarray:
    """(IQM RMS position error, IQM return, mean crash rate) of a (runs x episodes x 3) score array."""
    from rliable import metrics

    return np.array([metrics.aggregate_iqm(scores[..., 0]), metrics.aggregate_iqm(scores[..., 1]),
                     metrics.aggregate_mean(scores[..., 2])])


def _seeded_interval_estimates(score_dict, func, reps):
    """rliable's get_interval_estimates, reproducible: its StratifiedBootstrap draws its indices from
    numpy's global RNG (np.random.choice), not from the random_state it is given, so the global RNG is
    seeded for the call and restored afterwards."""
    from rliable import library as rly

    saved = np.random.get_state()
    np.random.seed(BOOTSTRAP_SEED)
    try:
        return rly.get_interval_estimates(score_dict, func, task_bootstrap=True, reps=reps,
                                          random_state=np.random.RandomState(BOOTSTRAP_SEED))
    finally:
        np.random.set_state(saved)


def aggregate(cells: list[dict]) -> list[dict]:
    """Per (task, tier, entry): IQM RMS position error, IQM return, mean crash rate, P(improvement)
    over the reference passivity controller; each with a 95 % stratified-bootstrap CI."""
    from rliable import metrics

    warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
    groups: dict[tuple, list[dict]] = {}
    for c in cells:
        groups.setdefault((c["task"], c["tier"], c["entry"]), []).append(c)
    rows = []
    for (task, tier, entry), group in sorted(groups.items()):
        row = {"task": task, "tier": tier, "entry": entry, "policy": group[0]["policy"],
               "action_mode": group[0]["action_mode"], "train_tier": group[0]["train_tier"],
               "runs": len(group), "episodes": len(group[0]["episodes"])}
        # one bootstrap for the three metrics: scores (runs x episodes x 3)
        scores = np.stack([_matrix(group, "rms_position_error"), _matrix(group, "return"),
                           _matrix(group, "crashed")], axis=-1)
        point, ci = _seeded_interval_estimates({"x": scores}, _three_metrics, BOOTSTRAP_REPS)
        for k, name in enumerate(("rms_position_error_iqm", "return_iqm", "crash_rate")):
            row[name] = float(point["x"][k])
            row[name.replace("_iqm", "") + "_ci"] = [float(ci["x"][0, k]), float(ci["x"][1, k])]
        ref = groups.get((task, tier, REFERENCE))
        if ref is not None and entry != REFERENCE:
            x = _matrix(group, "rms_position_error", -1.0)  # higher is better for rliable
            y = _matrix(ref, "rms_position_error", -1.0)
            point, ci = _seeded_interval_estimates({"p": (x, y)}, metrics.probability_of_improvement,
                                                   POI_BOOTSTRAP_REPS)
            row["prob_improvement"] = float(np.asarray(point["p"]).reshape(-1)[0])
            row["prob_improvement_ci"] = [float(v) for v in np.asarray(ci["p"]).reshape(-1)[:2]]
        rows.append(row)
    return rows


# ------------------------------------------------------------------------------------- render
def _fmt(v: float, ci: list[float], digits: int) -> str:
    return f"{v:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def render_markdown(data: dict) -> str:
    meta = data["meta"]
    lines = [
        "# SoftPVTOL-v0 leaderboard",
        "",
        f"<!-- Generated by `{meta['command']}` (re-render only: `python baselines/leaderboard.py --from-json`) "
        f"from `baselines/results/leaderboard.json`. Do not edit by hand. -->",
        "",
        f"Generated by `{meta['command']}` at commit `{meta['commit']}` on {meta['date']}; "
        "the job list is `baselines/leaderboard.yml`, the per-run results are in "
        "`baselines/results/leaderboard.json`.",
        "",
        f"Each entry is evaluated on the same {meta['episodes']} seeded episodes per task and tier (seeds "
        f"{meta['eval_seed']} + i; training seeds are below 500,000). PPO entries have {meta['seeds']} training seeds "
        "each. Point estimates: IQM (interquartile mean) over runs x episodes of the RMS position error [m] and of "
        "the return, and the mean crash rate. Brackets: 95 % stratified-bootstrap CIs over runs and episodes "
        f"(rliable, {meta['bootstrap_reps']} replications; {meta['poi_bootstrap_reps']} for P(better)). "
        "P(better): rliable's probability that the entry has a "
        f"lower RMS position error than `{REFERENCE}` on an episode, with a CI over training seeds only "
        "(rliable's pair bootstrap does not resample episodes). Lower error, higher return, lower "
        "crash rate are better.",
        "",
    ]
    if meta.get("missing_jobs"):
        lines += [f"Missing jobs (not yet run): {len(meta['missing_jobs'])}.", ""]
    by_task: dict[str, list[dict]] = {}
    for r in data["aggregates"]:
        by_task.setdefault(r["task"], []).append(r)
    tier_order = meta["tiers"]
    for task in meta["tasks"]:
        rows = by_task.get(task, [])
        lines += [f"## {task}", "",
                  "| tier | policy | runs | RMS position error [m] | crash rate | return | P(better than "
                  f"{REFERENCE}) |", "|---|---|---|---|---|---|---|"]
        for r in sorted(rows, key=lambda r: (tier_order.index(r["tier"]), _entry_order(r["entry"]))):
            p = _fmt(r["prob_improvement"], r["prob_improvement_ci"], 2) if "prob_improvement" in r else "—"
            err = _fmt(r["rms_position_error_iqm"], r["rms_position_error_ci"], 3)
            crash = _fmt(r["crash_rate"], r["crash_rate_ci"], 2)
            ret = _fmt(r["return_iqm"], r["return_ci"], 0)
            lines.append(f"| {r['tier']} | {r['entry']} | {r['runs']} | {err} | {crash} | {ret} | {p} |")
        lines.append("")
    lines += ["![IQM RMS position error per tier](baselines/results/leaderboard.png)", ""]
    return "\n".join(lines)


def _entry_order(entry: str) -> tuple:
    order = ["passivity-paper", "passivity-exact", "passivity-bounded", "PPO-actuators", "PPO-virtual", "PPO-residual"]
    for i, prefix in enumerate(order):
        if entry.startswith(prefix):
            return (i, entry)
    return (len(order), entry)


def render_chart(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks, tiers = data["meta"]["tasks"], data["meta"]["tiers"]
    fig, axes = plt.subplots(1, len(tasks), figsize=(7 * len(tasks), 4.5), squeeze=False)
    every = sorted({r["entry"] for r in data["aggregates"]}, key=_entry_order)
    colors = {e: plt.get_cmap("tab10")(i % 10) for i, e in enumerate(every)}  # one colour per entry everywhere
    for ax, task in zip(axes[0], tasks):
        rows = [r for r in data["aggregates"] if r["task"] == task]
        entries = sorted({r["entry"] for r in rows}, key=_entry_order)
        width = 0.8 / max(len(entries), 1)
        for k, entry in enumerate(entries):
            xs, ys, lo, hi = [], [], [], []
            for i, tier in enumerate(tiers):
                r = next((r for r in rows if r["entry"] == entry and r["tier"] == tier), None)
                if r is None:
                    continue
                xs.append(i + (k - (len(entries) - 1) / 2) * width)
                ys.append(r["rms_position_error_iqm"])
                lo.append(r["rms_position_error_iqm"] - r["rms_position_error_ci"][0])
                hi.append(r["rms_position_error_ci"][1] - r["rms_position_error_iqm"])
            ax.bar(xs, ys, width, yerr=[lo, hi], capsize=2, label=entry, color=colors[entry])
        ax.set_xticks(range(len(tiers)), tiers)
        ax.set_yscale("log")
        ax.set_ylabel("IQM RMS position error [m] (95 % CI)")
        ax.set_title(task)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)


# ------------------------------------------------------------------------------------------ main
def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def build(root: Path = RUNS_DIR, spec: Path = SPEC_FILE) -> dict:
    s = load_spec(spec)
    cells, missing = collect(root, spec)
    if not cells:
        raise ConfigError(f"no results under {root}; run python baselines/run_jobs.py first")
    meta = {"command": COMMAND, "commit": _commit(), "date": _dt.date.today().isoformat(),
            "tasks": list(s["tasks"]), "tiers": list(s["evaluation"]["tiers"]),
            "episodes": int(s["evaluation"]["episodes"]), "eval_seed": int(s["evaluation"]["seed"]),
            "seeds": len(s["seeds"]), "bootstrap_reps": BOOTSTRAP_REPS, "poi_bootstrap_reps": POI_BOOTSTRAP_REPS,
            "bootstrap_seed": BOOTSTRAP_SEED,
            "reference": REFERENCE, "missing_jobs": missing}
    return {"meta": meta, "aggregates": aggregate(cells), "cells": cells}


_META_KEYS = {"command": str, "commit": str, "date": str, "tasks": list, "tiers": list, "episodes": int,
              "eval_seed": int, "seeds": int, "bootstrap_reps": int, "poi_bootstrap_reps": int}
_ROW_NUMBERS = ("rms_position_error_iqm", "crash_rate", "return_iqm")
_ROW_CIS = ("rms_position_error_ci", "crash_rate_ci", "return_ci")


def validate_data(data, source: str) -> dict:
    """``data`` if it is a leaderboard JSON that renders, else ConfigError naming the first problem."""
    def bad(what: str):
        raise ConfigError(f"leaderboard JSON {source}: {what}; re-create it with python baselines/leaderboard.py")

    def number(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if not isinstance(data, dict):
        bad(f"expected an object with meta, aggregates and cells, got {type(data).__name__}")
    for key in ("meta", "aggregates", "cells"):
        if key not in data:
            bad(f"{key} is missing")
    meta = data["meta"]
    if not isinstance(meta, dict):
        bad("meta must be an object")
    for key, typ in _META_KEYS.items():
        if not isinstance(meta.get(key), typ) or isinstance(meta.get(key), bool):
            bad(f"meta.{key} must be a {typ.__name__}, got {meta.get(key)!r}")
    if not isinstance(data["aggregates"], list) or not isinstance(data["cells"], list):
        bad("aggregates and cells must be lists")
    for i, r in enumerate(data["aggregates"]):
        where = f"aggregates[{i}]"
        if not isinstance(r, dict):
            bad(f"{where} must be an object")
        for key in ("task", "tier", "entry"):
            if not isinstance(r.get(key), str):
                bad(f"{where}.{key} must be a string, got {r.get(key)!r}")
        if r["tier"] not in meta["tiers"]:
            bad(f"{where}.tier {r['tier']!r} is not one of meta.tiers {meta['tiers']}")
        if not isinstance(r.get("runs"), int):
            bad(f"{where}.runs must be an integer")
        for key in _ROW_NUMBERS + (("prob_improvement",) if "prob_improvement" in r else ()):
            if not number(r.get(key)):
                bad(f"{where}.{key} must be a finite number, got {r.get(key)!r}")
        for key in _ROW_CIS + (("prob_improvement_ci",) if "prob_improvement" in r else ()):
            ci = r.get(key)
            if not (isinstance(ci, list) and len(ci) == 2 and all(number(v) for v in ci)):
                bad(f"{where}.{key} must be a list of two finite numbers, got {ci!r}")
    return data


def read_data(path: Path) -> dict:
    if path.is_dir():
        raise ConfigError(f"--json {path} is a directory; expected the leaderboard JSON file")
    if not path.is_file():
        raise ConfigError(f"no leaderboard JSON at {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"leaderboard JSON {path} is not valid JSON ({exc}); re-create it with python "
                          f"baselines/leaderboard.py") from None
    return validate_data(data, str(path))


def _check_output(path: Path, option: str) -> None:
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a directory; expected a file name")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {path}: {parent} is not a writable directory")


def _main(argv=None) -> int:
    ap = Parser(prog="leaderboard.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--from-json", action="store_true", help="only re-render from the committed JSON")
    ap.add_argument("--json", type=Path, default=RESULTS_JSON)
    ap.add_argument("--markdown", type=Path, default=LEADERBOARD_MD)
    ap.add_argument("--chart", type=Path, default=CHART_PNG)
    ap.add_argument("--root", type=Path, default=RUNS_DIR)
    ap.add_argument("--spec", type=Path, default=SPEC_FILE)
    args = ap.parse_args(argv)
    for path, option in ((args.markdown, "--markdown"), (args.chart, "--chart")) + (
            () if args.from_json else ((args.json, "--json"),)):
        _check_output(path, option)
    if args.from_json:
        data = read_data(args.json)
    else:
        if not args.root.is_dir():
            ap.error(f"--root {args.root} is not a directory")
        data = build(args.root, args.spec)
        atomic_write_text(args.json, json.dumps(data, indent=1))
    atomic_write_text(args.markdown, render_markdown(data))
    render_chart(data, args.chart)
    print(f"wrote {args.markdown} and {args.chart}" + ("" if args.from_json else f" from {args.json}"))
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("leaderboard.py")
    return run_main(_main, argv, prog="leaderboard.py")


if __name__ == "__main__":
    sys.exit(main())
