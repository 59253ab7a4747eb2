"""Score any policy as the leaderboard scores its entries, and rank it among the committed ones.

:func:`score` runs a policy factory (``factory(env)``, :mod:`softpvtol_gym.baselines.user_policy`) on the
leaderboard's seeded test episodes (the spec's ``evaluation.seed`` + i, its tasks and tiers, or a part of them),
with the same windowed metrics (:func:`~softpvtol_gym.baselines.evaluation.run_episodes`), the same statistics
(:func:`~softpvtol_gym.baselines.leaderboard.stats.aggregate`: IQM and 95 % stratified-bootstrap CI of each
window; one run, so the CIs are over episodes) and the per-robot compute
(:func:`~softpvtol_gym.baselines.evaluation.per_robot_compute_us`), then places it, per (task, tier, window),
among the rows of a committed leaderboard JSON (:func:`rank`): its rank by IQM, the strongest committed entry
there, and whether their CIs are disjoint. A (task, tier) the leaderboard treats as deterministic (identical
episodes) counts the run once there too, as the leaderboard does.
"""

from __future__ import annotations

from pathlib import Path

from softpvtol_gym.baselines.config.hyperparams import MAX_EPISODES
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import COMPUTE_SINGLE, per_robot_compute_us, run_episodes
from softpvtol_gym.baselines.leaderboard.headline import verdict
from softpvtol_gym.baselines.leaderboard.render import fmt_single, fmt_window
from softpvtol_gym.baselines.leaderboard.spec import SPEC_FILE, load_spec
from softpvtol_gym.baselines.leaderboard.stats import WINDOWS, aggregate, read_data
from softpvtol_gym.baselines.leaderboard.summary import SUMMARY_FILE
from softpvtol_gym.baselines.user_policy import as_policy, failure_words
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

#: the committed leaderboard a score is ranked against by default: its summary, shipped with the package
LEADERBOARD_JSON = SUMMARY_FILE
#: the row label of the scored policy
ENTRY = "your policy"


def score(policy_factory, tasks=None, tiers=None, episodes: int | None = None, action_mode: str = "actuators",
          leaderboard: Path | None = LEADERBOARD_JSON, spec: Path = SPEC_FILE, name: str = ENTRY) -> dict:
    """Score ``policy_factory`` (``factory(env)`` -> a policy with ``predict``, an SB3 model or a callable
    observation -> action; called afresh for every task and tier and for the compute pass) on the leaderboard's
    test episodes: ``tasks`` and ``tiers`` (default: the spec's), the first ``episodes`` of them (default: the
    spec's ``evaluation.episodes``), in ``action_mode``. ``leaderboard``: the committed JSON to rank against (None:
    no ranking). Returns ``{"meta", "episodes": task -> tier -> episodes (each with compute_us_single),
    "aggregates": the leaderboard's rows for the policy, "ranking": :func:`rank`'s rows}``."""
    s = load_spec(spec)
    ev = s["evaluation"]
    tasks = _subset(tasks, s["tasks"], "tasks")
    tiers = _subset(tiers, ev["tiers"], "tiers")
    episodes = int(ev["episodes"]) if episodes is None else episodes
    if isinstance(episodes, bool) or not isinstance(episodes, int) or not 1 <= episodes <= MAX_EPISODES:
        raise ConfigError(f"episodes must be an integer in [1, {MAX_EPISODES:,}], got {episodes!r}")
    if action_mode not in ACTION_MODES:
        raise ConfigError(f"action_mode must be one of {list(ACTION_MODES)}, got {action_mode!r}")
    if not callable(policy_factory):
        raise ConfigError(f"policy_factory must be a callable that takes the env, got a "
                          f"{type(policy_factory).__name__}")
    board = None if leaderboard is None else read_data(Path(leaderboard))
    seed = int(ev["seed"])
    results, cells = {}, []
    for task in tasks:
        for tier in tiers:
            eps = run_episodes(_policy(policy_factory, action_mode, task, tier), action_mode, task, tier, episodes,
                               seed, timing=True)
            us = per_robot_compute_us(_policy(policy_factory, action_mode, task, tier), action_mode, task, tier, seed)
            eps = [{**e, COMPUTE_SINGLE: us} for e in eps]
            results.setdefault(task, {})[tier] = eps
            cells.append({"entry": name, "policy": "user", "action_mode": action_mode, "task": task, "tier": tier,
                          "train_task": task, "train_tier": None, "recipe": None, "seed": 0, "episodes": eps})
    fixed = None if board is None else {(r["task"], r["tier"]) for r in board["aggregates"] if r.get("deterministic")}
    rows = aggregate(cells, deterministic=fixed)
    meta = {"policy": name, "action_mode": action_mode, "tasks": tasks, "tiers": tiers, "episodes": episodes,
            "test_seed": seed, "leaderboard": None if leaderboard is None else str(leaderboard)}
    return {"meta": meta, "episodes": results, "aggregates": rows,
            "ranking": [] if board is None else rank(rows, board)}


def _subset(chosen, valid: list, what: str) -> list:
    if chosen is None:
        return list(valid)
    chosen = [chosen] if isinstance(chosen, str) else list(chosen)
    wrong = [c for c in chosen if c not in valid]
    if not chosen or wrong:
        raise ConfigError(f"{what} must be a non-empty list of the leaderboard's {what} {valid}, got {chosen!r}")
    return list(dict.fromkeys(chosen))


def _policy(factory, action_mode: str, task: str, tier: str):
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode=action_mode, task=task, tier=tier)
    try:
        made = factory(env)
    except ConfigError:
        raise
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - the user's code: its error in one line
        raise ConfigError(f"the policy factory failed on {task}/{tier}: it {failure_words(exc)}") from None
    return as_policy(made, env, f"the policy factory (on {task}/{tier}, {action_mode} mode)")


def _key(v) -> float:
    return float("inf") if v is None else float(v)


def rank(rows: list[dict], board: dict) -> list[dict]:
    """Per (task, tier, window) of :data:`~.stats.WINDOWS` that ``board`` (a leaderboard JSON) holds: the scored
    policy's row, its ``rank`` by IQM among the committed entries there (1: lowest error; ties rank it first),
    ``of`` (entries + 1), the strongest committed entry (``best``), and ``verdict``: "better" or "worse" by the
    headline's rules (:func:`~.headline.verdict`: significantly more crashes lose, else disjoint 95 % CIs decide),
    else "overlap"."""
    out = []
    for row in rows:
        here = [r for r in board["aggregates"] if (r["task"], r["tier"]) == (row["task"], row["tier"])]
        for window, metric, what in WINDOWS:
            others = [r for r in here if f"{metric}_iqm" in r]
            if not others or f"{metric}_iqm" not in row:
                continue
            mine = _key(row[f"{metric}_iqm"])
            best = min(sorted(others, key=lambda r: r["entry"]), key=lambda r: _key(r[f"{metric}_iqm"]))
            winner, _ = verdict(best, row, metric)  # the headline's rules: crashes (Fisher), then the CIs
            verdict_ = {"learned": "better", "model-based": "worse"}.get(winner, "overlap")
            out.append({"task": row["task"], "tier": row["tier"], "window": window, "metric": metric, "what": what,
                        "rank": 1 + sum(_key(r[f"{metric}_iqm"]) < mine for r in others), "of": len(others) + 1,
                        "row": row, "best": best, "verdict": verdict_})
    return out


def ranking_markdown(result: dict) -> str:
    """The ranking of a :func:`score` result as a Markdown table (and the per-robot compute per task and tier)."""
    lines = ["| task | tier | window | your IQM [95 % CI] | rank | strongest committed entry | its IQM [95 % CI] | "
             "CIs |", "|---|---|---|---|---|---|---|---|"]
    for r in result["ranking"]:
        lines.append(f"| {r['task']} | {r['tier']} | {r['what']} | {fmt_window(r['row'], r['metric'])} | "
                     f"{r['rank']} of {r['of']} | {r['best']['entry']} | {fmt_window(r['best'], r['metric'])} | "
                     f"{r['verdict']} |")
    compute = ", ".join(f"{r['task']}/{r['tier']} {fmt_single(r)}" for r in result["aggregates"])
    return "\n".join(lines) + f"\n\nPer-robot compute (µs per observation, one at a time): {compute}\n"
