"""Residual entries against their own base loops.

A residual policy acts on top of an analytic passivity loop (the env's ``controller_loop``). The leaderboard scores
that loop alone on the same episodes (its ``passivity-<loop>`` entry), so each residual entry can be read beside
it: a residual that makes its base loop worse in a window is marked on the page, not hidden in the tables.
"""

from __future__ import annotations

from softpvtol_gym.baselines.config.recipes import load_recipe
from softpvtol_gym.baselines.leaderboard.stats import WINDOWS
from softpvtol_gym.envs.config import EnvConfig

#: the mark after a window value that is worse than the entry's base loop there, and its footnote
WORSE = "▽"
WORSE_NOTE = (f"{WORSE}: a residual entry worse than its own base loop alone in that window (a higher IQM, a crash "
              "counting as worse than any value): the learned correction hurts there.")


def base_loop(row: dict) -> str | None:
    """The passivity loop under a residual row (its recipe's ``controller_loop``, else the env's default for the
    residual mode); None for a row that is not a residual."""
    if row.get("action_mode") != "residual":
        return None
    loop = load_recipe(row["recipe"])["controller_loop"] if row.get("recipe") else None
    return loop or EnvConfig(action_mode="residual").resolved_controller_loop


def worse(value: float | None, base: float | None) -> bool:
    """Whether an IQM ``value`` is worse than the base loop's ``base`` (None: a crashed window, worse than any
    value)."""
    if value is None:
        return base is not None
    return base is not None and value > base


def base_loop_comparisons(data: dict) -> list[dict]:
    """Per residual row of ``data["aggregates"]`` whose base loop is on the leaderboard for the same task and tier:
    ``{"task", "tier", "entry", "base", "row", "base_row", "worse": {window: bool}}`` (windows of
    :data:`~.stats.WINDOWS`), in the aggregates' order."""
    by_key = {(r["task"], r["tier"], r["entry"]): r for r in data["aggregates"]}
    out = []
    for row in data["aggregates"]:
        loop = base_loop(row)
        base = by_key.get((row["task"], row["tier"], f"passivity-{loop}")) if loop else None
        if base is None:
            continue
        flags = {name: worse(row.get(f"{metric}_iqm"), base.get(f"{metric}_iqm"))
                 for name, metric, _ in WINDOWS if f"{metric}_iqm" in row and f"{metric}_iqm" in base}
        out.append({"task": row["task"], "tier": row["tier"], "entry": row["entry"], "base": base["entry"],
                    "row": row, "base_row": base, "worse": flags})
    return out


def worse_windows(data: dict) -> dict[tuple[str, str, str], set[str]]:
    """(task, tier, entry) -> the per-episode metrics (window metrics of :data:`~.stats.WINDOWS`) in which that
    residual entry is worse than its base loop."""
    metric = {name: m for name, m, _ in WINDOWS}
    return {(c["task"], c["tier"], c["entry"]): {metric[w] for w, bad in c["worse"].items() if bad}
            for c in base_loop_comparisons(data)}
