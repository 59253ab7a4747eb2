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
from baselines.jobs import (
    EVAL_FILE,
    REPO_ROOT,
    RUNS_DIR,
    SPEC_FILE,
    evaluations_of,
    load_jobs,
    load_spec,
    missing_evaluations,
    read_eval,
)

RESULTS_JSON = Path(__file__).resolve().parent / "results" / "leaderboard.json"
LEADERBOARD_MD = REPO_ROOT / "LEADERBOARD.md"
CHART_PNG = Path(__file__).resolve().parent / "results" / "leaderboard.png"
REFERENCE = "passivity-bounded"   # the strongest analytic loop, the env's default (docs/control.md)
BOOTSTRAP_REPS = 2000
POI_BOOTSTRAP_REPS = 300  # rliable's probability of improvement runs scipy per episode: slow
BOOTSTRAP_SEED = 0
COMMAND = "python baselines/run_jobs.py && python baselines/leaderboard.py"


def entry_label(job: dict, task: str | None = None) -> str:
    """The row label of a job evaluated on ``task`` (default: its own): a PPO entry names the tier it was
    trained on, and the task too where that is not the one evaluated."""
    if job["policy"] == "ppo":
        where = job["train_tier"] if task in (None, job["task"]) else f"{job['task']}, {job['train_tier']}"
        return f"PPO-{job['action_mode']} (trained on {where})"
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
        evaluations = evaluations_of(rec)
        lost = missing_evaluations(job, rec)
        if lost:
            missing.append(f"{job.name} on {', '.join(f'{t}/{tier}' for t, tier in lost)}")
        for task in job.eval_tasks:  # what the spec lists now (a result may hold more)
            for tier, episodes in evaluations.get(task, {}).items():
                if tier not in job.eval_tiers:
                    continue
                cells.append({
                    "entry": entry_label(j, task), "policy": j["policy"], "action_mode": j["action_mode"],
                    "task": task, "train_task": j["task"], "train_tier": j["train_tier"], "tier": tier,
                    "seed": j["seed"], "timesteps": j.get("timesteps") or None, "checkpoint": rec["checkpoint"],
                    "train_seconds": rec["train_seconds"],
                    "eval_seed": j["eval_seed"], "episodes": episodes, "summary": _summary(episodes),
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
               "action_mode": group[0]["action_mode"], "train_task": group[0].get("train_task", task),
               "train_tier": group[0]["train_tier"],
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


# ------------------------------------------------------------------------------------- headline
HEADLINE_TASKS = ("track_paper", "track_random")  # the tracking tasks of issue 16's goal


def _policy_key(row: dict) -> tuple:
    """A learned policy across the tasks it is evaluated on: (action mode, training task, training tier)."""
    return (row["action_mode"], row.get("train_task", row["task"]), row["train_tier"])


def _disjoint_below(a: list[float], b: list[float]) -> bool:
    return a[1] < b[0]


def headline(data: dict) -> dict | None:
    """The best learned policy against the strongest analytic controller on every (tracking task, tier).

    The learned policy is one policy for all of them (an action mode trained on one task and tier): of
    the learned policies evaluated on every tier of every tracking task of the leaderboard, the one with
    the smallest sum over (task, tier) of its IQM RMS position error relative to that of the strongest
    analytic controller there. The strongest analytic controller is chosen per (task, tier): the
    passivity entry with the lowest IQM RMS position error. None if no learned policy qualifies."""
    meta, rows = data["meta"], data["aggregates"]
    tasks = [t for t in HEADLINE_TASKS if t in meta["tasks"]]
    pairs = [(t, tier) for t in tasks for tier in meta["tiers"]]
    analytic = {}
    for t, tier in pairs:
        candidates = [r for r in rows if r["task"] == t and r["tier"] == tier and r["policy"] != "ppo"]
        if candidates:
            analytic[(t, tier)] = min(candidates, key=lambda r: r["rms_position_error_iqm"])
    learned: dict[tuple, dict] = {}
    for r in rows:
        if r["policy"] == "ppo" and (r["task"], r["tier"]) in analytic:
            learned.setdefault(_policy_key(r), {})[(r["task"], r["tier"])] = r
    complete = {k: v for k, v in learned.items() if len(v) == len(pairs)}
    if not pairs or len(analytic) < len(pairs) or not complete:
        return None

    def relative(k):
        return sum(complete[k][p]["rms_position_error_iqm"] / analytic[p]["rms_position_error_iqm"] for p in pairs)

    best = min(sorted(complete), key=relative)
    out = []
    for t, tier in pairs:
        a, b = analytic[(t, tier)], complete[best][(t, tier)]
        out.append({"task": t, "tier": tier, "analytic": a, "learned": b,
                    "lower": b["rms_position_error_iqm"] < a["rms_position_error_iqm"],
                    "disjoint": _disjoint_below(b["rms_position_error_ci"], a["rms_position_error_ci"]),
                    "crash_no_higher": b["crash_rate"] <= a["crash_rate"]})
    mode, train_task, train_tier = best
    return {"policy": f"PPO-{mode} trained on {train_task} ({train_tier} tier)", "rows": out}


README_BLOCK = ("leaderboard.py headline", "baselines/results/leaderboard.json")  # README block: name, source


def headline_markdown(data: dict, heading: bool = True) -> list[str]:
    """The headline section of LEADERBOARD.md (``heading=False``: without its title, for the README)."""
    h = headline(data)
    if h is None:
        return []
    n = len(h["rows"])
    counts = [sum(r[k] for r in h["rows"]) for k in ("lower", "disjoint", "crash_no_higher")]
    lines = [
        *(["## Headline: learned vs analytic control on the tracking tasks", ""] if heading else []),
        f"One learned policy, **{h['policy']}**, against the strongest analytic controller of each task and tier "
        "(the passivity entry with the lowest IQM RMS position error there). The policy is the learned entry "
        "evaluated on every tier of both tracking tasks with the smallest sum of its error relative to that "
        "controller's (`headline()` in `baselines/leaderboard.py`). "
        f"Its IQM RMS position error is lower in {counts[0]} of {n} (task, tier) pairs, with disjoint 95 % CIs "
        f"in {counts[1]} of {n}; its crash rate is no higher in {counts[2]} of {n}.", "",
        "| task | tier | strongest analytic | its RMS position error [m] | its crash rate | learned RMS position "
        "error [m] | learned crash rate | learned lower? | CIs disjoint? |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in h["rows"]:
        a, b = r["analytic"], r["learned"]
        err = [_fmt(x["rms_position_error_iqm"], x["rms_position_error_ci"], 3) for x in (a, b)]
        crash = [_fmt(x["crash_rate"], x["crash_rate_ci"], 2) for x in (a, b)]
        yes = ["yes" if r[k] else "no" for k in ("lower", "disjoint")]
        lines.append(f"| {r['task']} | {r['tier']} | {a['entry']} | {err[0]} | {crash[0]} | {err[1]} | {crash[1]} | "
                     f"{yes[0]} | {yes[1]} |")
    return lines + [""]


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
    lines += headline_markdown(data)
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
    lines += _budget_markdown(data)
    lines += ["![IQM RMS position error per tier](baselines/results/leaderboard.png)", ""]
    return "\n".join(lines)


def training_budgets(data: dict) -> list[dict]:
    """Per learned cell (action mode, training task, training tier): the training steps of its jobs (from
    the job records) and the wall time of each seed's training (``train_seconds``; None where a job
    was evaluated from an existing model and its time is not on record)."""
    cells: dict[tuple, dict] = {}
    for c in data["cells"]:
        if c["policy"] != "ppo":
            continue
        key = (c["action_mode"], c.get("train_task", c["task"]), c["train_tier"])
        cells.setdefault(key, {})[c["seed"]] = (c.get("timesteps"), c["train_seconds"])
    out = []
    for (mode, task, tier), seeds in sorted(cells.items()):
        steps = sorted({s for s, _ in seeds.values() if s is not None})
        seconds = [t for _, t in seeds.values() if t is not None]
        out.append({"action_mode": mode, "train_task": task, "train_tier": tier, "seeds": len(seeds),
                    "timesteps": steps, "train_seconds": sorted(seconds)})
    return out


def _budget_markdown(data: dict) -> list[str]:
    rows = training_budgets(data)
    if not rows:
        return []
    lines = ["## Training budgets", "",
             "Per learned cell: the PPO steps of each seed (the spec's budget) and the wall time of its training "
             "(`train_seconds` in the job records: median and range over the seeds; one process per job with one torch "
             "thread). Wall time depends on the machine and on what else it ran meanwhile, so compare cells by steps; "
             "the commit that added these results says on what machine, and at what load, the jobs ran.",
             "", "| policy | trained on | seeds | steps per seed | training wall time per seed [s] |",
             "|---|---|---|---|---|"]
    for r in rows:
        steps = ", ".join(f"{s:,}" for s in r["timesteps"]) or "not on record"
        t = r["train_seconds"]
        wall = f"{float(np.median(t)):.0f} [{t[0]:.0f}, {t[-1]:.0f}]" if t else "not on record"
        if t and len(t) < r["seeds"]:
            wall += f" ({len(t)} of {r['seeds']} seeds on record)"
        lines.append(f"| PPO-{r['action_mode']} | {r['train_task']}, {r['train_tier']} | {r['seeds']} | {steps} | "
                     f"{wall} |")
    return lines + [""]


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
    if args.markdown.resolve() == LEADERBOARD_MD.resolve():  # the committed outputs: the README's block too
        from baselines import readme

        readme.write_block(*README_BLOCK, "\n".join(headline_markdown(data, heading=False)))
    print(f"wrote {args.markdown} and {args.chart}" + ("" if args.from_json else f" from {args.json}"))
    return 0


def main(argv=None) -> int:
    from baselines._extras import require

    require("leaderboard.py")
    return run_main(_main, argv, prog="leaderboard.py")


if __name__ == "__main__":
    sys.exit(main())
