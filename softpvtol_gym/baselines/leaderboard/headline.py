"""The headline of the leaderboard: learned against model-based control, chosen from the aggregate rows of
:func:`~.stats.aggregate` (the whole-episode headline over the tracking tasks, and one verdict per task, tier
and window)."""

from __future__ import annotations

import numpy as np

from softpvtol_gym.baselines.leaderboard.spec import is_learned
from softpvtol_gym.baselines.leaderboard.stats import WINDOWS, learned_name

HEADLINE_TASKS = ("track_paper", "track_random")  # the tracking tasks: the headline


def _policy_key(row: dict) -> tuple:
    """A learned policy across the tasks it is evaluated on: (its short name, training task, training tier)."""
    return (learned_name(row), row.get("train_task", row["task"]), row["train_tier"])


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
        candidates = [r for r in rows if r["task"] == t and r["tier"] == tier and not is_learned(r["policy"])]
        if candidates:
            analytic[(t, tier)] = min(candidates, key=lambda r: r["rms_position_error_iqm"])
    learned: dict[tuple, dict] = {}
    for r in rows:
        if is_learned(r["policy"]) and (r["task"], r["tier"]) in analytic:
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
    name, train_task, train_tier = best
    return {"policy": f"{name} trained on {train_task} ({train_tier} tier)", "rows": out}


def _key(v: float | None) -> float:
    """A window statistic for comparisons: None (crashed) is worse than any value."""
    return np.inf if v is None else float(v)


def window_headline(data: dict) -> list[dict]:
    """Learned against model-based control per (task, tier, window) of :data:`WINDOWS`: the strongest learned entry
    (the PPO or distilled entry with the lowest IQM of the window's metric there) against the strongest model-based
    one (the analytic entry, passivity or MPC, with the lowest), both chosen per (task, tier, window), so each side
    gets its best. Each side's strongest entry is chosen on the held-out selection episodes where every row there
    holds them (``selected_on: "selection"``), and reported, like the verdict, on the test episodes; rows without
    them (results from before the selection episodes) are chosen on the test episodes (``"test"``). ``winner``:
    "learned" or "model-based" where that side's 95 % CI lies entirely below the other's and its crash rate is no
    higher; "neither" otherwise (overlapping CIs, or a lower error bought with more crashes). Windows the rows do
    not hold (results scored before the windows existed) are left out."""
    meta, rows = data["meta"], data["aggregates"]
    out = []
    for task in meta["tasks"]:
        for tier in meta["tiers"]:
            here = [r for r in rows if r["task"] == task and r["tier"] == tier]
            for window, metric, what in WINDOWS:
                have = [r for r in here if f"{metric}_iqm" in r or (metric == "rms_position_error" and
                                                                      "rms_position_error_iqm" in r)]
                learned = [r for r in have if is_learned(r["policy"])]
                model = [r for r in have if not is_learned(r["policy"])]
                if not learned or not model:
                    continue
                held_out = all("selection" in r for r in have)

                def best(side, metric=metric, held_out=held_out):
                    def score(x):
                        return _key((x["selection"] if held_out else x)[f"{metric}_iqm"])
                    return min(sorted(side, key=lambda x: x["entry"]), key=score)

                a, b = best(model), best(learned)
                ci_a = [_key(v) for v in a[f"{metric}_ci"]]
                ci_b = [_key(v) for v in b[f"{metric}_ci"]]
                if ci_b[1] < ci_a[0] and b["crash_rate"] <= a["crash_rate"]:
                    winner = "learned"
                elif ci_a[1] < ci_b[0] and a["crash_rate"] <= b["crash_rate"]:
                    winner = "model-based"
                else:
                    winner = "neither"
                out.append({"task": task, "tier": tier, "window": window, "metric": metric, "what": what,
                            "model_based": a, "learned": b, "winner": winner,
                            "selected_on": "selection" if held_out else "test"})
    return out
