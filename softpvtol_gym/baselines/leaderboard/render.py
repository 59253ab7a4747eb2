"""Leaderboard rendering: the Markdown page and the chart, from the leaderboard JSON."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.evaluation import COMPUTE_OBSERVATIONS, COMPUTE_SINGLE, WINDOW_METRICS
from softpvtol_gym.baselines.leaderboard.base_loops import WORSE, WORSE_NOTE, base_loop_comparisons, worse_windows
from softpvtol_gym.baselines.leaderboard.headline import crash_counts, headline, tolerance_headline, window_headline
from softpvtol_gym.baselines.leaderboard.spec import is_learned
from softpvtol_gym.baselines.leaderboard.stats import (
    MIN_CI_VALUES,
    REFERENCE,
    TOLERANCE_KEY,
    WHOLE,
    WINDOWS,
    learned_name,
)
from softpvtol_gym.baselines.util.atomic import atomic_path
from softpvtol_gym.baselines.util.blocks import markers

#: the leaderboard JSON as the generated blocks name their source
SOURCE = "results/leaderboard.json"
#: the headline block (name, source) inside the leaderboard page (docs/leaderboard.md in a checkout)
HEADLINE_BLOCK = ("leaderboard.py headline", SOURCE)
#: the short summary block (name, source) for the README
SUMMARY_BLOCK = ("leaderboard.py summary", SOURCE)


def num(v: float | None) -> str:
    """A statistic for the tables: None is a crashed window (an IQM) or an unbounded bound (a CI)."""
    if v is None:
        return "crash"
    if v != 0 and abs(v) < 0.01:
        return f"{v:.1e}"
    return f"{v:.3f}"


#: the mark of a CI resampled from fewer than MIN_CI_VALUES values, and its footnote
FEW_VALUES = "†"
FEW_VALUES_NOTE = (f"{FEW_VALUES}: a CI resampled from fewer than {MIN_CI_VALUES} values (runs x episodes, or runs "
                   "on a deterministic task and tier): too few for the bootstrap to be trusted; read it as a rough "
                   "range.")


def ci_values(row: dict) -> int:
    """How many values a row's CIs resample (``ci_values``; for rows from before the key: runs x episodes, or runs
    on a deterministic task and tier)."""
    if "ci_values" in row:
        return row["ci_values"]
    return row["runs"] * (1 if row.get("deterministic") else row.get("episodes", 1))


def marks(row: dict) -> str:
    """The marks after a row's CI: † (fewer than MIN_CI_VALUES values), ‡ (a deterministic task and tier)."""
    few = "runs" in row and ci_values(row) < MIN_CI_VALUES
    return (f" {FEW_VALUES}" if few else "") + (" ‡" if row.get("deterministic") else "")


def fmt_window(row: dict, metric: str) -> str:
    """``IQM [lo, hi]`` of one metric of a row (crashed windows: "crash"; ``fraction_within_1cm``: its mean), with
    its marks (:func:`marks`); a row of one value (one run of a deterministic task and tier) as ``value (n = 1)``,
    without a CI; "—" where the row lacks it."""
    key = metric if metric == TOLERANCE_KEY else f"{metric}_iqm"
    if key not in row:
        return "—"
    if "runs" in row and ci_values(row) == 1:
        return f"{num(row[key])} (n = 1)" + marks(row)
    ci = row[f"{metric}_ci"]
    return f"{num(row[key])} [{num(ci[0])}, {num(ci[1])}]" + marks(row)


def _us(v: float | None) -> str:
    return "—" if v is None else f"{v:.0f}" if v >= 10 else f"{v:.1f}"


def fmt_single(row: dict) -> str:
    """The per-robot compute of a row (µs per observation, one at a time); "—" where it was not measured."""
    return _us(row.get(COMPUTE_SINGLE))


def fmt_us(row: dict, spread: bool = False) -> str:
    """The median µs per step of a row; ``spread``: with the worst episode's p99 and max."""
    text = _us(row.get("compute_us_per_step_median"))
    if spread and row.get("compute_us_per_step_p99") is not None:
        text += f" (p99 {_us(row['compute_us_per_step_p99'])}, max {_us(row.get('compute_us_per_step_max'))})"
    return text


WINNER = {"learned": "**learned**", "model-based": "**model-based**", "neither": "neither"}
#: what decided a cell (:func:`~.headline.verdict`)
DECIDED_BY = {"crashes": "crashes (Fisher p < 0.05)", "error": "error (CIs disjoint)", "overlap": "CIs overlap",
              "knife_edge": "within round-off", "no_roundoff_probe": "no round-off probe"}


def rules_sentence(data: dict) -> str:
    """The verdict's rules as the page states them (from the JSON's meta where it records them)."""
    meta = data["meta"]
    alpha = meta.get("crash_alpha", 0.05)
    return ("Each side's strongest entry is the one with the fewest crashes on the selection episodes, then the "
            f"lowest IQM there (`selection_rule`: `{meta.get('selection_rule', 'iqm')}`). A side wins a cell where "
            "the other crashes significantly more often (one-sided Fisher exact test on the crash counts, "
            f"p < {alpha:g}: decided by crashes); else where its 95 % CI lies entirely below the other's (decided by "
            "error); else neither. Crash counts are over every episode of a row (a learned entry: runs x episodes, "
            "an analytic one: its episodes), and the exact test is valid for unequal counts. On a deterministic task "
            "and tier (‡: every episode the same outcome) an analytic entry is one value (n = 1, no CI), and a win "
            "there must also exceed how far round-off alone moves the metric (the job's round-off probe: the "
            f"episode again from starts moved by {meta.get('roundoff_shift_m', 1e-9):g} m in x and z; a cell within "
            "it is a knife edge, decided by neither side).")


def headline_markdown(data: dict, heading: bool = True) -> list[str]:
    """The headline section of the leaderboard page (``heading=False``: its body only, the generated block):
    learned against model-based control per (task, tier, window) (:func:`~.headline.window_headline`)."""
    rows = window_headline(data)
    if not rows:
        return []
    counts = {w: sum(r["winner"] == w for r in rows) for w in ("model-based", "learned", "neither")}
    mb = [f"{r['task']}/{r['tier']}/{r['window']}" for r in rows if r["winner"] == "model-based"]
    lines = [
        *(["## Headline: learned vs model-based control, per time window", ""] if heading else []),
        "Per task, tier and time window: the strongest learned entry against the strongest model-based controller "
        "(`window_headline()` in `softpvtol_gym/baselines/leaderboard/headline.py`). " + rules_sentence(data)
        + " Windows: whole episode, first quarter (transient), last half (steady), and the max error over the last "
        "5 s; a window an episode crashed in, and the whole episode of a crashed episode, count as worse than any "
        "value. ‡: a deterministic task and tier: one value per run (its mean), a learned entry's CI over training "
        f"seeds only. {FEW_VALUES_NOTE} "
        + _selection_sentence(data, rows)
        + " µs/robot: the per-robot compute, the median µs of the entry's `predict` on one observation at a time "
        f"(`compute_us_single`, a pass of its own over the first {COMPUTE_OBSERVATIONS:,} observations of a test "
        "episode in the order "
        "of its closed loop; wall time, machine- and load-dependent; — where not measured).",
        "",
        f"**Model-based control wins {counts['model-based']} of {len(rows)} (task, tier, window) cells, learned "
        f"control {counts['learned']}, neither {counts['neither']}.**"
        + (f" Model-based wins: {', '.join(mb)}." if mb else " Model-based control wins nowhere."),
        "",
        "| task | tier | window | strongest model-based | its error [m] | crashes | µs/robot | strongest learned | "
        "its error [m] | crashes | µs/robot | winner | decided by |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        a, b = r["model_based"], r["learned"]
        lines.append(f"| {r['task']} | {r['tier']} | {r['what']} | {a['entry']} | {fmt_window(a, r['metric'])} | "
                     f"{fmt_crashes(a)} | {fmt_single(a)} | {b['entry']} | {fmt_window(b, r['metric'])} | "
                     f"{fmt_crashes(b)} | {fmt_single(b)} | {WINNER[r['winner']]} | "
                     f"{DECIDED_BY.get(r.get('decided_by'), '—')} |")
    return lines + [""] + tolerance_markdown(data)


def fmt_crashes(row: dict) -> str:
    """``crashed / episodes`` of a row."""
    crashed, n = crash_counts(row)
    return f"{crashed}/{n}"


def tolerance_markdown(data: dict) -> list[str]:
    """The tolerance verdict (:func:`~.headline.tolerance_headline`): per task and tier, which side keeps the
    position within 1 cm of the reference more of the time, with both sides' mean actuator effort."""
    rows = tolerance_headline(data)
    if not rows:
        return []
    counts = {w: sum(r["winner"] == w for r in rows) for w in ("model-based", "learned", "neither")}
    lines = [
        "### Good enough: time within 1 cm", "",
        "Per task and tier, the share of the episode's time limit with the position error below "
        f"{data['meta'].get('tolerance_m', 0.01) * 100:g} cm (`fraction_within_1cm`, the mean over episodes; a crashed "
        "episode's remaining time counts as outside), the strongest entry of each side chosen on the selection "
        "episodes by fewest crashes, then the highest share (`tolerance_headline()`). A side wins where its 95 % CI "
        "lies entirely above the other's (on a deterministic task and tier: by more than round-off moves it). "
        "Effort: the mean over steps of the applied actuators' squared, normalised size (`control_effort`, the "
        "env's effort measure), outside the verdict.", "",
        f"**Time within 1 cm: model-based control wins {counts['model-based']} of {len(rows)} (task, tier) cells, "
        f"learned control {counts['learned']}, neither {counts['neither']}.**", "",
        "| task | tier | strongest model-based | within 1 cm | effort | strongest learned | within 1 cm | effort | "
        "winner | decided by |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        a, b = r["model_based"], r["learned"]
        lines.append(f"| {r['task']} | {r['tier']} | {a['entry']} | {fmt_window(a, r['metric'])} | {fmt_effort(a)} | "
                     f"{b['entry']} | {fmt_window(b, r['metric'])} | {fmt_effort(b)} | {WINNER[r['winner']]} | "
                     f"{DECIDED_BY.get(r['decided_by'], '—')} |")
    return lines + [""]


def fmt_effort(row: dict) -> str:
    return "—" if "control_effort_mean" not in row else f"{row['control_effort_mean']:.3f}"


def _selection_sentence(data: dict, rows: list[dict]) -> str:
    """How the headline's entries were chosen: on held-out selection episodes, or (results from before them) on
    the test episodes it reports."""
    meta = data["meta"]
    if rows and all(r["selected_on"] == "selection" for r in rows):
        return (f"Each side's strongest entry is chosen on {meta.get('selection_episodes', '?')} held-out selection "
                f"episodes per run (seeds {meta.get('selection_seed', '?')} + i) and reported on the disjoint test "
                f"episodes (seeds {meta.get('test_seed', meta['eval_seed'])} + i), so the choice does not flatter "
                "the numbers shown.")
    return ("These results predate the held-out selection episodes: each side's strongest entry is chosen on the "
            "same test episodes it is reported on, which flatters the winner of a close race (re-score: "
            "`python baselines/run_jobs.py --rescore`).")


def policy_headline_markdown(data: dict) -> list[str]:
    """One learned policy against the strongest analytic controller on every (tracking task, tier) (the
    whole-episode headline, :func:`~.headline.headline`), whole-episode RMS."""
    h = headline(data)
    if h is None:
        return []
    n = len(h["rows"])
    counts = [sum(r[k] for r in h["rows"]) for k in ("lower", "disjoint", "crash_no_higher")]
    lines = [
        "## One learned policy on every tracking task and tier", "",
        f"One learned policy, **{h['policy']}**, against the strongest analytic controller of each task and tier "
        "(the analytic entry with the lowest IQM RMS position error there). The policy is the learned entry "
        "evaluated on every tier of both tracking tasks with the smallest sum of its error relative to that "
        "controller's (`headline()` in `softpvtol_gym/baselines/leaderboard/headline.py`). "
        f"Its whole-episode IQM RMS position error is lower in {counts[0]} of {n} (task, tier) pairs, with disjoint "
        f"95 % CIs in {counts[1]} of {n}; its crash rate is no higher in {counts[2]} of {n}.", "",
        "| task | tier | strongest analytic | its RMS position error [m] | its crash rate | learned RMS position "
        "error [m] | learned crash rate | learned lower? | CIs disjoint? |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in h["rows"]:
        a, b = r["analytic"], r["learned"]
        err = [fmt_ci(x["rms_position_error_iqm"], x["rms_position_error_ci"], 3) for x in (a, b)]
        crash = [fmt_ci(x["crash_rate"], x["crash_rate_ci"], 2) for x in (a, b)]
        yes = ["yes" if r[k] else "no" for k in ("lower", "disjoint")]
        lines.append(f"| {r['task']} | {r['tier']} | {a['entry']} | {err[0]} | {crash[0]} | {err[1]} | {crash[1]} | "
                     f"{yes[0]} | {yes[1]} |")
    return lines + [""]


def base_loop_markdown(data: dict) -> list[str]:
    """The residual entries beside their own base loops (:mod:`~.base_loops`): per task, tier and window, the
    residual's IQM and its base loop's, marked where the residual is worse."""
    rows = base_loop_comparisons(data)
    if not rows:
        return []
    hurt = [r for r in rows if any(r["worse"].values())]
    cells = sum(len(r["worse"]) for r in rows)
    worse_cells = sum(sum(r["worse"].values()) for r in rows)
    lines = ["## Residual entries beside their base loops", "",
             "A residual policy corrects an analytic loop (its `controller_loop`); the loop alone is scored on the "
             "same episodes. Each cell: the residual's IQM error, then its base loop's. "
             f"{WORSE_NOTE} The residual is worse than its base loop in {worse_cells} of {cells} (task, tier, entry, "
             f"window) cells, and in at least one window in {len(hurt)} of {len(rows)} (task, tier, entry) rows.", "",
             "| task | tier | residual entry | base loop | " + " | ".join(what for _, _, what in WINDOWS) + " |",
             "|---" * (4 + len(WINDOWS)) + "|"]
    for r in rows:
        values = []
        for name, metric, _ in WINDOWS:
            if name not in r["worse"]:
                values.append("—")
                continue
            mark = f" {WORSE}" if r["worse"][name] else ""
            values.append(f"{num(r['row'][f'{metric}_iqm'])}{mark} vs {num(r['base_row'][f'{metric}_iqm'])}")
        lines.append(f"| {r['task']} | {r['tier']} | {r['entry']} | {r['base']} | " + " | ".join(values) + " |")
    return lines + [""]


# ------------------------------------------------------------------------------------- render
def fmt_ci(v: float, ci: list[float], digits: int) -> str:
    return f"{v:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def summary_markdown(data: dict, page: str = "docs/leaderboard.md") -> str:
    """The README's short summary of the headline (at most 8 lines): who wins per (task, tier, window), learned
    or the strongest model-based controller, and the compute per step."""
    rows = window_headline(data)
    if not rows:
        return f"No learned and model-based entries share a task and tier yet; see [the leaderboard]({page})."
    counts = {w: sum(r["winner"] == w for r in rows) for w in ("model-based", "learned", "neither")}
    windows = [w for w in WINDOWS if any(r["window"] == w[0] for r in rows)]
    tasks = list(dict.fromkeys(r["task"] for r in rows))
    by = {(r["task"], r["window"]): [] for r in rows}
    for r in rows:
        by[(r["task"], r["window"])].append(r)
    us = {side: [x[side].get(COMPUTE_SINGLE) for x in rows] for side in ("model_based", "learned")}
    us = {k: [v for v in vs if v is not None] for k, vs in us.items()}
    compute = (" Per-robot compute (median µs of `predict` on one observation): strongest model-based "
               f"{min(us['model_based']):.0f}-{max(us['model_based']):.0f}, strongest learned "
               f"{min(us['learned']):.0f}-{max(us['learned']):.0f}." if us["model_based"] and us["learned"] else "")
    tolerance = tolerance_headline(data)
    within = ("" if not tolerance else
              f" Time within 1 cm of the reference: model-based wins "
              f"{sum(r['winner'] == 'model-based' for r in tolerance)} of {len(tolerance)} (task, tier) cells, "
              f"learned {sum(r['winner'] == 'learned' for r in tolerance)}.")
    lines = [f"Learned vs the strongest model-based controller per task, tier and time window (each side's entry "
             f"chosen on held-out episodes by fewest crashes, then error; a side wins with significantly fewer "
             f"crashes or a 95 % CI entirely below the other's): **model-based wins {counts['model-based']} of "
             f"{len(rows)} cells, learned {counts['learned']}, neither {counts['neither']}**.{within}{compute} Per "
             f"task and window, the tiers each side wins ([full leaderboard]({page})):", "",
             "| task | " + " | ".join(what for _, _, what in windows) + " |", "|---" * (len(windows) + 1) + "|"]

    def cell(items):
        mb = [r["tier"] for r in items if r["winner"] == "model-based"]
        le = [r["tier"] for r in items if r["winner"] == "learned"]
        return "; ".join([f"model-based: {', '.join(mb)}"] * bool(mb) + [f"learned: {', '.join(le)}"] * bool(le)) \
            or "neither"

    for task in tasks:
        lines.append(f"| {task} | " + " | ".join(cell(by.get((task, w), [])) for w, _, _ in windows) + " |")
    return "\n".join(lines)


def render_markdown(data: dict, chart: str = "../results/leaderboard.png") -> str:
    """The leaderboard page; ``chart``: the chart's path relative to the page (its image link)."""
    meta = data["meta"]
    lines = [
        "# SoftPVTOL-v0 leaderboard",
        "",
        f"<!-- Generated by `{meta['command']}` (re-render only: `python baselines/leaderboard.py --from-json`) "
        f"from `{SOURCE}`. Do not edit by hand. -->",
        "",
        f"Generated by `{meta['command']}` on {meta['date']} (the commit is in the JSON's `meta`); "
        "the job list is `softpvtol_gym/baselines/data/leaderboard.yml`, the per-run results are in "
        f"`{SOURCE}`.",
        "",
        f"Each entry is evaluated on the same {meta['episodes']} seeded test episodes per task and tier (seeds "
        f"{meta.get('test_seed', meta['eval_seed'])} + i; training seeds are below 500,000)"
        + (f", and on {meta['selection_episodes']} held-out selection episodes (seeds {meta['selection_seed']} + i), "
           "on which the headline chooses each side's strongest entry" if meta.get("selection_episodes") else "")
        + (f"; learned entries through the `{meta['inference']}` forward pass" if meta.get("inference") else "")
        + f". Learned entries have {meta['seeds']} training seeds "
        "each. Point estimates: IQM (interquartile mean) over runs x episodes of the RMS position error [m] (whole "
        "episode, first quarter, last half) and of the max position error over the last 5 s [m], IQM of the return, "
        "the mean crash rate, and the means of the share of the time limit within 1 cm of the reference and of the "
        "actuator effort. Brackets: 95 % stratified-bootstrap CIs over runs and episodes "
        f"(rliable, {meta['bootstrap_reps']} replications; {meta['poi_bootstrap_reps']} for P(better)). "
        "A window that an episode crashed in (and the whole episode of a crashed episode) counts as worse than any "
        "value (\"crash\": the IQM or the CI bound "
        "reaches crashed windows). ‡: a deterministic task and tier (an entry there has identical episodes: one "
        "reference, one initial state): each run counts once, as the mean of its episodes, so the CI is over "
        "training seeds only, and an analytic entry has one value (n = 1, no CI). P(better): rliable's "
        "probability that the entry has a "
        f"lower RMS position error than `{REFERENCE}` on an episode, with a CI over training seeds only "
        "(rliable's pair bootstrap does not resample episodes). µs/step: the median wall time of the policy's own "
        "`predict` per control step and env (the per-env share of a batch of all the episodes), on the machine and "
        "at the load the jobs ran; in brackets the worst episode's 99th percentile and maximum (which includes "
        "one-off costs such as compiling on the first call). µs/robot: the per-robot compute, the median wall time "
        "of `predict` on one observation at a time in one thread (`compute_us_single`, measured in a pass of its own "
        f"on the first {COMPUTE_OBSERVATIONS:,} observations of each run's first test episode, in the order of its "
        "closed loop, so that "
        "a controller with memory does each step's work as in the episode; the median over runs); — where not "
        "measured. "
        f"{FEW_VALUES_NOTE} Lower error, higher return, lower crash rate are better.",
        "",
    ]
    if meta.get("missing_jobs"):
        lines += [f"Missing or stale jobs (not yet run or re-scored): {len(meta['missing_jobs'])}.", ""]
    body = headline_markdown(data, heading=False)
    if body:
        start, end = markers(*HEADLINE_BLOCK)
        lines += headline_markdown(data)[:2] + [start] + body[:-1] + [end, ""]
    lines += policy_headline_markdown(data)
    lines += base_loop_markdown(data)
    bad = worse_windows(data)
    by_task: dict[str, list[dict]] = {}
    for r in data["aggregates"]:
        by_task.setdefault(r["task"], []).append(r)
    tier_order = meta["tiers"]
    for task in meta["tasks"]:
        rows = by_task.get(task, [])
        lines += [f"## {task}", "",
                  "| tier | policy | runs x episodes | RMS position error [m] | RMS, first quarter [m] | RMS, last "
                  "half [m] | max, last 5 s [m] | within 1 cm | effort | crash rate | return | µs/step | µs/robot | "
                  f"P(better than {REFERENCE}) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in sorted(rows, key=lambda r: (tier_order.index(r["tier"]), _entry_order(r["entry"]))):
            p = fmt_ci(r["prob_improvement"], r["prob_improvement_ci"], 2) if "prob_improvement" in r else "—"
            hurt = bad.get((r["task"], r["tier"], r["entry"]), set())

            def flag(metric: str, hurt=hurt) -> str:
                return f" {WORSE}" if metric in hurt else ""

            err = (fmt_window(r, WHOLE) if f"{WHOLE}_iqm" in r else
                   fmt_ci(r["rms_position_error_iqm"], r["rms_position_error_ci"], 3) + marks(r)) + flag(WHOLE)
            windows = " | ".join(fmt_window(r, m) + flag(m) for m in (*WINDOW_METRICS, TOLERANCE_KEY))
            windows += f" | {fmt_effort(r)}"
            crash = fmt_ci(r["crash_rate"], r["crash_rate_ci"], 2) + marks(r).replace(" ‡", "")
            ret = fmt_ci(r["return_iqm"], r["return_ci"], 0) + marks(r).replace(" ‡", "")
            lines.append(f"| {r['tier']} | {r['entry']} | {r['runs']} x {r.get('episodes', '?')} | {err} | {windows} | "
                         f"{crash} | {ret} | {fmt_us(r, spread=True)} | {fmt_single(r)} | {p} |")
        lines.append("")
    lines += _budget_markdown(data)
    lines += [f"![IQM RMS position error per tier]({chart})", ""]
    return "\n".join(lines)


def training_budgets(data: dict) -> list[dict]:
    """Per learned cell (its short name, training task, training tier): the training steps of its jobs (from
    the job records) and the wall time of each seed's training (``train_seconds``; None where a job
    was evaluated from an existing model and its time is not on record)."""
    cells: dict[tuple, dict] = {}
    for c in data["cells"]:
        if is_learned(c["policy"]):
            cells.setdefault((learned_name(c), c.get("train_task", c["task"]), c["train_tier"]), {})[c["seed"]] = c
    out = []
    for (name, task, tier), seeds in sorted(cells.items()):
        first = next(iter(seeds.values()))
        out.append({"name": name, "policy": first["policy"], "action_mode": first["action_mode"], "train_task": task,
                    "train_tier": tier, "recipe": first.get("recipe"), "teacher": first.get("teacher"),
                    "seeds": len(seeds),
                    "timesteps": sorted({c["timesteps"] for c in seeds.values() if c.get("timesteps") is not None}),
                    "train_seconds": sorted(c["train_seconds"] for c in seeds.values()
                                            if c["train_seconds"] is not None)})
    return out


def _budget_markdown(data: dict) -> list[str]:
    rows = training_budgets(data)
    if not rows:
        return []
    lines = ["## Training budgets", "",
             "Per learned cell: the PPO steps of each seed (the spec's budget; a distilled student takes no PPO "
             "steps, its samples are in the job's distill.json) and the wall time of its training "
             "(`train_seconds` in the job records: median and range over the seeds; one process per job with one torch "
             "thread). Wall time depends on the machine and on what else it ran meanwhile, so compare cells by steps; "
             "the commit that added these results says on what machine, and at what load, the jobs ran.",
             "", "| policy | trained on | seeds | steps per seed | training wall time per seed [s] |",
             "|---|---|---|---|---|"]
    for r in rows:
        steps = ", ".join(f"{s:,}" for s in r["timesteps"]) or (
            "none (distilled: distill.json)" if r["policy"] == "distilled" else "not on record")
        t = r["train_seconds"]
        wall = f"{float(np.median(t)):.0f} [{t[0]:.0f}, {t[-1]:.0f}]" if t else "not on record"
        if t and len(t) < r["seeds"]:
            wall += f" ({len(t)} of {r['seeds']} seeds on record)"
        lines.append(f"| {r['name']} | {r['train_task']}, {r['train_tier']} | {r['seeds']} | {steps} | "
                     f"{wall} |")
    return lines + [""]


def _entry_order(entry: str) -> tuple:
    order = ["passivity-paper", "passivity-exact", "passivity-bounded", "passivity-integral", "passivity-extended",
             "mpc", "PPO-actuators", "PPO-virtual", "PPO-residual", "PPO "]
    for i, prefix in enumerate(order):
        if entry.startswith(prefix):
            return (i, entry)
    return (len(order), entry)


def render_chart(data: dict, path: Path) -> None:
    """Write the chart of :func:`chart_png` to ``path`` (atomically)."""
    png = chart_png(data)
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(png)


def chart_png(data: dict) -> bytes:
    """The leaderboard chart (IQM RMS position error per task, tier and entry, with CIs) as PNG bytes."""
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
    tmp = io.BytesIO()  # in memory: the caller writes the bytes atomically (render_chart, atomic_write_all)
    try:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    finally:
        plt.close(fig)
    return tmp.getvalue()
