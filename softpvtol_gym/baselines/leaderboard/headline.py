"""The headline of the leaderboard: learned against model-based control, chosen from the aggregate rows of
:func:`~.stats.aggregate` (the whole-episode headline over the tracking tasks, and one verdict per task, tier
and window)."""

from __future__ import annotations

import numpy as np
from scipy.stats import fisher_exact

from softpvtol_gym.baselines.leaderboard.spec import is_learned
from softpvtol_gym.baselines.leaderboard.stats import CRASH_ALPHA, TOLERANCE_KEY, WINDOWS, learned_name

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
    mixture = next(iter(complete[best].values())).get("trained_on")
    return {"policy": f"{name} trained on {mixture or f'{train_task} ({train_tier} tier)'}", "rows": out}


def _key(v: float | None) -> float:
    """A window statistic for comparisons: None (crashed) is worse than any value."""
    return np.inf if v is None else float(v)


def crash_counts(row: dict) -> tuple[int, int]:
    """(crashed episodes, episodes) of a row: ``crashes`` of ``crash_episodes`` (rows from before them: the crash
    rate times the values its CIs resample)."""
    if "crashes" in row and "crash_episodes" in row:
        return int(row["crashes"]), int(row["crash_episodes"])
    n = int(row.get("ci_values", row["runs"] * row.get("episodes", 1)))
    return int(round(row["crash_rate"] * n)), n


def more_crashes(a: dict, b: dict) -> float:
    """The p-value of "row ``a`` crashes more often than row ``b``": a one-sided Fisher exact test on their crash
    counts (:func:`crash_counts`), exact for any two counts, equal or not (scipy, with rliable)."""

    (ca, na), (cb, nb) = crash_counts(a), crash_counts(b)
    if ca * nb <= cb * na:  # not even the point estimate is higher
        return 1.0
    return float(fisher_exact([[ca, na - ca], [cb, nb - cb]], alternative="greater").pvalue)


def _point(row: dict, metric: str) -> float:
    return _key(row.get(metric) if metric == TOLERANCE_KEY else row.get(f"{metric}_iqm"))


def _ci(row: dict, metric: str) -> list[float]:
    return [_key(v) for v in row[f"{metric}_ci"]]


def knife_edge(a: dict, b: dict, metric: str) -> bool | None:
    """Whether the difference of two rows of a deterministic task and tier is within what round-off alone moves
    (the larger :func:`~.stats.roundoff_sensitivity` of the two rows that have one; an unbounded one: True); None
    where neither row has a round-off probe (the difference cannot be told from round-off)."""
    spreads = [r["roundoff_sensitivity"].get(metric) for r in (a, b) if "roundoff_sensitivity" in r]
    if not spreads:
        return None
    if any(v is None for v in spreads):
        return True
    va, vb = _point(a, metric), _point(b, metric)
    return bool(abs(va - vb) <= max(spreads))  # a crashed IQM against a finite one: never within


def verdict(a: dict, b: dict, metric: str, higher_is_better: bool = False, crash_rule: bool = True) -> tuple[str, str]:
    """(winner, decided_by) of model-based row ``a`` against learned row ``b`` on ``metric``, by the documented
    rules, in order: ``crashes`` (a side crashes significantly more often, :func:`more_crashes` below
    :data:`~.stats.CRASH_ALPHA`: the other side wins; only with ``crash_rule``), ``error`` (one side's 95 % CI lies
    entirely on the better side of the other's: it wins), else ``overlap`` (neither). On a deterministic task and
    tier an ``error`` win needs the difference to be larger than round-off moves it (:func:`knife_edge`), else it
    is ``knife_edge`` (neither; ``no_roundoff_probe`` where no row has a probe)."""
    if crash_rule and more_crashes(b, a) < CRASH_ALPHA:
        return "model-based", "crashes"
    if crash_rule and more_crashes(a, b) < CRASH_ALPHA:
        return "learned", "crashes"
    ci_a, ci_b = _ci(a, metric), _ci(b, metric)
    if higher_is_better:
        ci_a, ci_b = [-ci_a[1], -ci_a[0]], [-ci_b[1], -ci_b[0]]
    winner = "learned" if ci_b[1] < ci_a[0] else "model-based" if ci_a[1] < ci_b[0] else "neither"
    if winner == "neither":
        return winner, "overlap"
    if a.get("deterministic") or b.get("deterministic"):
        edge = knife_edge(a, b, metric)
        if edge is None:
            return "neither", "no_roundoff_probe"
        if edge:
            return "neither", "knife_edge"
    return winner, "error"


def strongest(side: list[dict], metric: str, held_out: bool, higher_is_better: bool = False) -> dict:
    """The strongest row of one side by :data:`~.stats.SELECTION_RULE`: the lowest crash rate, then the best IQM of
    ``metric`` (the mean for ``fraction_within_1cm``, highest first), both on the selection episodes where
    ``held_out`` (else, results from before them, on the test episodes); ties by entry name."""
    def score(x):
        src = x["selection"] if held_out else x
        value = _point(src, metric)
        return (src.get("crash_rate", x["crash_rate"]), -value if higher_is_better else value)
    return min(sorted(side, key=lambda x: x["entry"]), key=score)


def window_headline(data: dict) -> list[dict]:
    """Learned against model-based control per (task, tier, window) of :data:`WINDOWS`: the strongest learned entry
    (PPO or distilled) against the strongest model-based one (passivity or MPC), each chosen per (task, tier,
    window) by :data:`~.stats.SELECTION_RULE` (:func:`strongest`: fewest crashes, then the lowest IQM of the
    window's metric), so each side gets its best. The choice is made on the held-out selection episodes where every
    row there holds them (``selected_on: "selection"``) and reported, like the verdict, on the test episodes; rows
    without them (results from before the selection episodes) are chosen on the test episodes (``"test"``).
    ``winner`` and ``decided_by``: :func:`verdict` (significantly fewer crashes wins; else a 95 % CI entirely below
    the other's; else "neither"; a deterministic cell's win must exceed its round-off sensitivity). Windows the rows
    do not hold (results scored before the windows existed) are left out."""
    meta, rows = data["meta"], data["aggregates"]
    out = []
    for task in meta["tasks"]:
        for tier in meta["tiers"]:
            here = [r for r in rows if r["task"] == task and r["tier"] == tier]
            for window, metric, what in WINDOWS:
                have = [r for r in here if f"{metric}_iqm" in r]
                learned = [r for r in have if is_learned(r["policy"])]
                model = [r for r in have if not is_learned(r["policy"])]
                if not learned or not model:
                    continue
                held_out = all("selection" in r for r in have)
                a, b = strongest(model, metric, held_out), strongest(learned, metric, held_out)
                winner, decided_by = verdict(a, b, metric)
                out.append({"task": task, "tier": tier, "window": window, "metric": metric, "what": what,
                            "model_based": a, "learned": b, "winner": winner, "decided_by": decided_by,
                            "deterministic": bool(a.get("deterministic")),
                            "crash_p": {"model_based_more": more_crashes(a, b), "learned_more": more_crashes(b, a)},
                            "selected_on": "selection" if held_out else "test"})
    return out


def tolerance_headline(data: dict) -> list[dict]:
    """Which side keeps the position within 1 cm of the reference more of the time, per (task, tier): the strongest
    entry of each side by :data:`~.stats.SELECTION_RULE` on ``fraction_within_1cm`` (fewest crashes, then the
    highest mean share on the selection episodes), and :func:`verdict` on the test episodes' mean share (higher is
    better; a crash already counts as time outside, so no separate crash rule). Rows without the metric are left
    out."""
    meta, rows = data["meta"], data["aggregates"]
    out = []
    for task in meta["tasks"]:
        for tier in meta["tiers"]:
            have = [r for r in rows if r["task"] == task and r["tier"] == tier and TOLERANCE_KEY in r]
            learned = [r for r in have if is_learned(r["policy"])]
            model = [r for r in have if not is_learned(r["policy"])]
            if not learned or not model:
                continue
            held_out = all(TOLERANCE_KEY in r.get("selection", {}) for r in have)
            a = strongest(model, TOLERANCE_KEY, held_out, higher_is_better=True)
            b = strongest(learned, TOLERANCE_KEY, held_out, higher_is_better=True)
            winner, decided_by = verdict(a, b, TOLERANCE_KEY, higher_is_better=True, crash_rule=False)
            out.append({"task": task, "tier": tier, "metric": TOLERANCE_KEY, "model_based": a, "learned": b,
                        "winner": winner, "decided_by": decided_by, "deterministic": bool(a.get("deterministic")),
                        "selected_on": "selection" if held_out else "test"})
    return out
