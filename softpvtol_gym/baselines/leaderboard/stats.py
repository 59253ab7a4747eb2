"""Leaderboard statistics (rliable): the job results collected into cells, IQMs with stratified-bootstrap CIs,
and the JSON that holds them (built and validated; its headline: :mod:`~.headline`).

Per (task, tier, entry) row: the IQM and 95 % CI of the whole-episode RMS position error (``rms_position_error``:
over the steps each episode lived, so a crashed episode's value is its RMS up to the crash, descriptive only), of
the return and of the crash rate, and of each window of :data:`WINDOWS` (``<metric>_iqm``, ``<metric>_ci``; the
whole episode's verdict metric ``rms_position_error_whole`` scores a crashed episode +inf, like every window);
the crash counts the crash verdict tests (``crashes`` of ``crash_episodes``: runs x episodes, or runs on a
deterministic task and tier); the mean and 95 % CI of ``fraction_within_1cm`` (the share of the time limit within
1 cm of the reference) and of ``control_effort`` (``control_effort_mean``); on a deterministic task and tier,
``roundoff_sensitivity``: how far each headline metric moves when the start is moved by round-off-level amounts
(the job's ``roundoff`` episodes, :data:`~.episodes.ROUNDOFF_SHIFT_M`); plus ``compute_us_per_step_median`` (the
median over the row's episodes of their median per-step time: the per-env share of a batch),
``compute_us_per_step_p99`` / ``_max`` (the worst episode's) and ``compute_us_single`` (the per-robot compute: the
median over the row's runs of each run's figure, measured in a pass of its own on one observation at a time).
``ci_values``: how many values the CIs resample (runs x episodes, or runs on a deterministic task and tier); a CI
from fewer than :data:`MIN_CI_VALUES` is marked on the page. ``selection``: the crash rate, the IQM of each
headline metric and the mean ``fraction_within_1cm`` on the held-out selection episodes, on which
:func:`~.headline.window_headline` chooses each side's strongest entry (fewest crashes first, then the best IQM:
:data:`SELECTION_RULE`) before it reports it on the test episodes.
Two rules keep the CIs honest:

* Crashed windows (None in an episode) are scored +inf: worse than any value, never dropped. The IQM trims
  the worst quarter, so it stays finite while at most a quarter of a sample's windows crashed; beyond that it
  is None ("crashed": the interquartile range reaches crashed windows). A CI bound is None where the
  bootstrap's percentile reaches crashed replicates (upper: unbounded). Percentiles of window metrics use
  the nearest replicate outward (numpy's "lower" / "higher"), never an interpolation towards +inf.
* Deterministic tasks and tiers: where the episodes are all the same in what the policies get (detected from
  the data, :func:`deterministic_pairs`: some entry's runs have identical episodes), a run's episodes are one
  observation, not many: every row of that (task, tier) counts each run once, as the mean over its episodes
  (``deterministic: true``), so the CI comes from the training seeds only, and an analytic entry (one run) has
  a single value with a CI of zero width.
"""

from __future__ import annotations

import datetime as _dt
import math
import subprocess
import warnings
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import (
    COMPUTE_PASS,
    COMPUTE_SINGLE,
    EPISODE_METRICS,
    TIMING_METRICS,
    TOLERANCE_M,
    WINDOW_METRICS,
    identical_episodes,
    summarize,
    window_scores,
)
from softpvtol_gym.baselines.leaderboard.distilled import student_fields
from softpvtol_gym.baselines.leaderboard.episodes import ROUNDOFF_SHIFT_M
from softpvtol_gym.baselines.leaderboard.jobs import (
    EVAL_FILE,
    RUNS_DIR,
    SPEC_FILE,
    evaluations_of,
    load_jobs,
    load_spec,
    read_eval,
    selections_of,
    stale_evaluations,
)
from softpvtol_gym.baselines.leaderboard.spec import is_learned, selection_seed
from softpvtol_gym.baselines.util.safe_load import loads_json

#: how each side's strongest entry is chosen on the selection episodes: the lowest crash rate, then the best IQM
SELECTION_RULE = "crashes_then_iqm"
#: the crash verdict: a one-sided Fisher exact test on the crash counts of the two rows, at this level
CRASH_TEST, CRASH_ALPHA = "fisher_exact_one_sided", 0.05
TOLERANCE_KEY = "fraction_within_1cm"
REFERENCE = "passivity-bounded"   # the strongest analytic loop, the env's default (docs/control.md)
BOOTSTRAP_REPS = 2000
POI_BOOTSTRAP_REPS = 300  # rliable's probability of improvement runs scipy per episode: slow
BOOTSTRAP_SEED = 0
#: a CI resampled from fewer values than this is marked (a dagger) on the page
MIN_CI_VALUES = 10
COMMAND = "python baselines/run_jobs.py && python baselines/leaderboard.py"
#: the per-episode metrics every result must hold (results without the windows and the timing are
#: stale, re-scored by ``run-jobs --rescore``)
BASE_METRICS = tuple(k for k in EPISODE_METRICS if k not in WINDOW_METRICS)
#: the whole episode's verdict metric: ``rms_position_error`` with a crashed episode scored +inf (worse than any
#: finished one), computed from the episodes here, not recorded
WHOLE = "rms_position_error_whole"
#: the windows of the headline: (name, per-episode metric, what it is)
WINDOWS = (("whole", WHOLE, "RMS, whole episode"),
           ("transient", "rms_position_error_transient", "RMS, first quarter"),
           ("steady", "rms_position_error_steady", "RMS, last half"),
           ("final_5s", "max_position_error_final_5s", "max, last 5 s"))


def learned_name(row: dict) -> str:
    """The short name of a learned job or row (no training tier): ``PPO <recipe>``, ``PPO-<action mode>`` or
    ``distilled <teacher>[ <variant>]``."""
    if row["policy"] == "distilled":
        return f"distilled {row['teacher']}" + (f" {row['variant']}" if row.get("variant") else "")
    return f"PPO {row['recipe']}" if row.get("recipe") else f"PPO-{row['action_mode']}"


def entry_label(job: dict, task: str | None = None) -> str:
    """The row label of a job evaluated on ``task`` (default: its own): a learned entry names the tier it was
    trained on, and the task too where that is not the one evaluated."""
    if is_learned(job["policy"]):
        where = student_fields(job).get("trained_on") or (
            job["train_tier"] if task in (None, job["task"]) else f"{job['task']}, {job['train_tier']}")
        return f"{learned_name(job)} (trained on {where})"
    return job["policy"]


# ------------------------------------------------------------------------------------ collect
def collect(root: Path = RUNS_DIR, spec: Path = SPEC_FILE, inference: str | None = None) -> tuple[list[dict],
                                                                                                 list[str]]:
    """Every (job, evaluation tier) as a cell with its per-episode metrics (test episodes under ``episodes``,
    selection episodes under ``selection``); and the missing job names. ``inference``: the forward pass the learned
    results must have been scored with (default: the spec's)."""
    cells, missing = [], []
    for job in load_jobs(spec, inference=inference):
        path = job.folder(root) / EVAL_FILE
        if not path.is_file():
            missing.append(job.name)
            continue
        rec = read_eval(path)
        j = rec["job"]
        if (j.get("policy"), j.get("task"), j.get("seed")) != (job.policy, job.task, job.seed):
            raise ConfigError(f"{path} holds the result of another job ({j.get('policy')}, {j.get('task')}, seed "
                              f"{j.get('seed')}); expected {job.name}")
        check_result(rec, path)
        evaluations = evaluations_of(rec)
        lost = stale_evaluations(job, rec)  # missing, or recorded before the windowed metrics
        if lost:
            have = {(t, tier) for t, tiers in evaluations.items() for tier in tiers}
            lacking = [f"{t}/{tier}" for t, tier in lost if (t, tier) not in have]
            stale = [f"{t}/{tier}" for t, tier in lost if (t, tier) in have]
            missing.append(f"{job.name} on {', '.join(lacking)}" if lacking and not stale else
                           f"{job.name}: " + "; ".join(
                               ([f"missing {', '.join(lacking)}"] if lacking else [])
                               + ([f"stale (re-score: run-jobs --rescore) {', '.join(stale)}"] if stale else [])))
        for task in job.eval_tasks:  # what the spec lists now (a result may hold more)
            for tier, episodes in evaluations.get(task, {}).items():
                if tier not in job.eval_tiers or (task, tier) in lost:
                    continue
                cells.append({
                    "entry": entry_label(j, task), "policy": j["policy"], "action_mode": j["action_mode"],
                    "recipe": j.get("recipe"), "teacher": j.get("teacher"), "variant": j.get("variant"),
                    **student_fields(j), "task": task, "train_task": j["task"],
                    "train_tier": j["train_tier"], "tier": tier,
                    "seed": j["seed"], "timesteps": j.get("timesteps") or None, "checkpoint": rec["checkpoint"],
                    "train_seconds": rec["train_seconds"],
                    "eval_seed": j["eval_seed"], "episodes": episodes, "summary": _summary(episodes),
                    "selection": selections_of(rec).get(task, {}).get(tier, []),
                    "roundoff": rec.get("roundoff", {}).get(task, {}).get(tier, []),
                })
    return cells, missing


def _number(v, allow_bool: bool = False) -> bool:
    return (isinstance(v, (int, float)) and (allow_bool or not isinstance(v, bool))) and math.isfinite(v)


#: the job fields a result must carry (name -> accepted types)
_RESULT_JOB_KEYS = {"policy": (str,), "action_mode": (str,), "task": (str,), "train_tier": (str, type(None)),
                    "seed": (int,), "eval_seed": (int,)}


def check_result(rec: dict, path: Path) -> dict:
    """``rec`` (a job's eval.json) if every field the leaderboard reads is there, of the right type and finite;
    else ConfigError naming the file and the field (nothing is written then)."""
    def bad(what: str):
        raise ConfigError(f"{path}: {what}; delete it and re-run the job (python baselines/run_jobs.py)")

    job = rec["job"]
    for key, types in _RESULT_JOB_KEYS.items():
        if key not in job:
            bad(f"job.{key} is missing")
        if not isinstance(job[key], types) or isinstance(job[key], bool):
            bad(f"job.{key} must be {' or '.join(t.__name__ for t in types)}, got {job[key]!r}")
    if job.get("recipe") is not None and not isinstance(job["recipe"], str):
        bad(f"job.recipe must be a recipe name or null, got {job['recipe']!r}")
    if job.get("timesteps") is not None and not (_number(job["timesteps"]) and isinstance(job["timesteps"], int)):
        bad(f"job.timesteps must be an integer, got {job['timesteps']!r}")
    if rec["checkpoint"] is not None and not isinstance(rec["checkpoint"], str):
        bad(f"checkpoint must be a path or null, got {rec['checkpoint']!r}")
    if rec["train_seconds"] is not None and not _number(rec["train_seconds"]):
        bad(f"train_seconds must be a finite number or null, got {rec['train_seconds']!r}")
    other = rec.get("eval_other_tasks", {})
    if not isinstance(other, dict):
        bad("eval_other_tasks must be an object (task -> tier -> episodes)")
    chosen = rec.get("selection", {})
    if not isinstance(chosen, dict):
        bad("selection must be an object (task -> tier -> episodes)")
    for where, tiers in [("eval", rec["eval"]), *((f"eval_other_tasks.{t}", v) for t, v in other.items()),
                         *((f"selection.{t}", v) for t, v in chosen.items())]:
        if not isinstance(tiers, dict):
            bad(f"{where} must be an object (tier -> episodes)")
        for tier, episodes in tiers.items():
            if not isinstance(episodes, list) or not episodes:
                bad(f"{where}.{tier} must be a non-empty list of episodes")
            for i, e in enumerate(episodes):
                if not isinstance(e, dict):
                    bad(f"{where}.{tier}[{i}] must be an object")
                for key in BASE_METRICS:
                    if key not in e and key == TOLERANCE_KEY:
                        continue  # recorded before the metric existed: stale, re-scored (collect reports it)
                    if key not in e:
                        bad(f"{where}.{tier}[{i}].{key} is missing")
                    if not _number(e[key], allow_bool=key == "crashed"):
                        bad(f"{where}.{tier}[{i}].{key} must be a finite number, got {e[key]!r}")
                for key in WINDOW_METRICS:  # absent: stale (collect reports it); null: a crashed window
                    if key in e and e[key] is None and not e["crashed"]:
                        bad(f"{where}.{tier}[{i}].{key} is null (a crashed window) in an episode that did not crash")
                    if key in e and e[key] is not None and not (_number(e[key]) and e[key] >= 0):
                        bad(f"{where}.{tier}[{i}].{key} must be a finite number >= 0 or null (crashed), "
                            f"got {e[key]!r}")
                for key in (*TIMING_METRICS, COMPUTE_SINGLE):
                    if key in e and not (_number(e[key]) and e[key] >= 0):
                        bad(f"{where}.{tier}[{i}].{key} must be a finite number >= 0, got {e[key]!r}")
    return rec


def _summary(episodes: list[dict]) -> dict:
    return summarize(episodes)


# ----------------------------------------------------------------------------------- statistics
def _matrix(cells: list[dict], key: str, sign: float = 1.0, per_run: bool = False) -> np.ndarray:
    """(runs x episodes) scores of one entry, runs sorted by seed (a crashed window: +inf); ``per_run``: (runs x
    1), each run's mean over its episodes (a deterministic task and tier: the episodes are one observation)."""
    rows = []
    for c in sorted(cells, key=lambda c: c["seed"]):
        x = sign * episode_scores(c["episodes"], key)
        rows.append([x.mean()] if per_run else x)
    return np.asarray(rows, dtype=float)


def episode_scores(episodes: list[dict], key: str) -> np.ndarray:
    """One score per episode: a window metric with a crashed window +inf, :data:`WHOLE` (the whole-episode RMS
    with a crashed episode +inf), or the recorded value of ``key``."""
    if key == WHOLE:
        return np.array([np.inf if e["crashed"] else float(e["rms_position_error"]) for e in episodes], dtype=float)
    if key in WINDOW_METRICS:
        return window_scores(episodes, key)
    return np.array([float(e[key]) for e in episodes], dtype=float)


def mean_intervals(scores: np.ndarray, reps: int = BOOTSTRAP_REPS) -> tuple[np.ndarray, np.ndarray]:
    """(means, 95 % CIs (2 x k)) of a (runs x episodes x k) array, from the stratified bootstrap of
    :func:`stratified_replicates`."""
    k = scores.shape[-1]
    replicates = stratified_replicates(scores, lambda x: x.reshape(-1, k).mean(axis=0), reps)
    return scores.reshape(-1, k).mean(axis=0), np.stack([np.percentile(replicates, 2.5, axis=0),
                                                         np.percentile(replicates, 97.5, axis=0)])


def deterministic_pairs(cells: list[dict]) -> set[tuple[str, str]]:
    """The (task, tier) pairs whose episodes are all the same in what the policies get (one reference, one
    initial state, no random effect), detected from the data: some entry there has more than one episode per
    run and every one of its runs has identical episodes (:func:`identical_episodes`, exactly). The analytic
    controllers, exact functions of their inputs, show it; a learned entry's episodes there can still differ
    by floating-point noise (a batched network sums in a batch-position dependent order and the closed loop
    carries 1e-16 along), which is not sampling variation."""
    groups: dict[tuple, list[dict]] = {}
    for c in cells:
        groups.setdefault((c["task"], c["tier"], c["entry"]), []).append(c)
    return {(task, tier) for (task, tier, _), group in groups.items()
            if all(len(c["episodes"]) > 1 and identical_episodes(c["episodes"]) for c in group)}


def _three_metrics(scores: np.ndarray) -> np.ndarray:
    """(IQM RMS position error, IQM return, mean crash rate) of a (runs x episodes x 3) score array."""
    from rliable import metrics

    return np.array([metrics.aggregate_iqm(scores[..., 0]), metrics.aggregate_iqm(scores[..., 1]),
                     metrics.aggregate_mean(scores[..., 2])])


def _iqms(scores: np.ndarray) -> np.ndarray:
    """The IQM of each metric of a (runs x episodes x k) score array (+inf where crashed windows reach the
    interquartile range)."""
    flat = np.sort(scores.reshape(-1, scores.shape[-1]), axis=0)  # scipy's trim_mean(0.25), all k at once
    cut = int(0.25 * flat.shape[0])
    with np.errstate(invalid="ignore"):
        return flat[cut:flat.shape[0] - cut].mean(axis=0)


def _seeded(call):
    """``call()`` with numpy's global RNG seeded (rliable's StratifiedBootstrap draws its indices from it, not
    from the random_state it is given) and restored afterwards."""
    saved = np.random.get_state()
    np.random.seed(BOOTSTRAP_SEED)
    try:
        return call()
    finally:
        np.random.set_state(saved)


def _seeded_interval_estimates(score_dict, func, reps):
    """rliable's get_interval_estimates, reproducible (:func:`_seeded`)."""
    from rliable import library as rly

    return _seeded(lambda: rly.get_interval_estimates(score_dict, func, task_bootstrap=True, reps=reps,
                                                      random_state=np.random.RandomState(BOOTSTRAP_SEED)))


def stratified_replicates(scores: np.ndarray, func, reps: int, seed: int = BOOTSTRAP_SEED) -> np.ndarray:
    """``func`` on ``reps`` stratified-bootstrap resamples of a (runs x episodes x k) array: rliable's
    StratifiedBootstrap with ``task_bootstrap=True`` (the episodes resampled with replacement, then, per
    element, a run drawn with replacement within its episode), vectorised and seeded (numpy Generator);
    (reps x k)."""
    rng = np.random.default_rng(seed)
    runs, episodes, k = scores.shape
    out = []
    chunk = max(1, 2_000_000 // scores.size)
    for start in range(0, reps, chunk):
        b = min(chunk, reps - start)
        run_idx = rng.integers(runs, size=(b, runs, episodes, k))
        episode_idx = rng.integers(episodes, size=(b, 1, episodes, 1))
        sample = scores[run_idx, episode_idx, np.arange(k)]  # (b, runs, episodes, k)
        out.extend(func(s) for s in sample)
    return np.asarray(out, dtype=float).reshape(reps, k)


def window_intervals(scores: np.ndarray, reps: int = BOOTSTRAP_REPS) -> tuple[np.ndarray, np.ndarray]:
    """(IQMs, 95 % CIs (2 x k)) of a (runs x episodes x k) array of window scores (+inf: crashed), from a
    stratified bootstrap over runs and episodes (:func:`stratified_replicates`); the percentiles take the nearest
    replicate outward, so a bound is +inf only where the replicates at that percentile are."""
    replicates = stratified_replicates(scores, _iqms, reps)
    lo = np.percentile(replicates, 2.5, axis=0, method="lower")
    hi = np.percentile(replicates, 97.5, axis=0, method="higher")
    return _iqms(scores), np.stack([lo, hi])


def _finite_or_none(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def aggregate(cells: list[dict], deterministic: set | None = None) -> list[dict]:
    """Per (task, tier, entry): IQM RMS position error, IQM return, mean crash rate, P(improvement)
    over the reference passivity controller, each with a 95 % stratified-bootstrap CI; the IQM and CI of each
    window metric (where the cells hold them), the median compute per step, the per-robot compute and the IQMs on
    the selection episodes (where the cells hold them). Rows whose every run has identical episodes count each run
    once (``deterministic``; module docstring); ``deterministic``: the (task, tier) pairs to treat so (default:
    :func:`deterministic_pairs` of ``cells``)."""
    from rliable import metrics

    warnings.filterwarnings("ignore", message="random_state is deprecated", category=FutureWarning)
    groups: dict[tuple, list[dict]] = {}
    for c in cells:
        groups.setdefault((c["task"], c["tier"], c["entry"]), []).append(c)
    rows = []
    fixed = deterministic_pairs(cells) if deterministic is None else set(deterministic)
    for (task, tier, entry), group in sorted(groups.items()):
        det = (task, tier) in fixed
        row = {"task": task, "tier": tier, "entry": entry, "policy": group[0]["policy"],
               "action_mode": group[0]["action_mode"], "train_task": group[0].get("train_task", task),
               "train_tier": group[0]["train_tier"], "recipe": group[0].get("recipe"),
               "teacher": group[0].get("teacher"), "variant": group[0].get("variant"),
               **{k: group[0][k] for k in ("privileged", "trained_on") if k in group[0]},
               "runs": len(group), "episodes": len(group[0]["episodes"]), "deterministic": det,
               "ci_over": ("none (one run of a deterministic task and tier)" if det and len(group) == 1 else
                           "training seeds only (a deterministic task and tier)" if det else
                           "runs and episodes" if len(group) > 1 else "episodes"),
               "ci_values": len(group) * (1 if det else len(group[0]["episodes"]))}
        # one bootstrap for the three metrics: scores (runs x episodes x 3)
        scores = np.stack([_matrix(group, "rms_position_error", per_run=det),
                           _matrix(group, "return", per_run=det),
                           _matrix(group, "crashed", per_run=det)], axis=-1)
        point, ci = _seeded_interval_estimates({"x": scores}, _three_metrics, BOOTSTRAP_REPS)
        for k, name in enumerate(("rms_position_error_iqm", "return_iqm", "crash_rate")):
            row[name] = float(point["x"][k])
            row[name.replace("_iqm", "") + "_ci"] = [float(ci["x"][0, k]), float(ci["x"][1, k])]
        crashed = _matrix(group, "crashed", per_run=det)
        row["crashes"], row["crash_episodes"] = int(round(crashed.sum())), int(crashed.size)
        windows = [WHOLE] + [k for k in WINDOW_METRICS if all(k in e for c in group for e in c["episodes"])]
        if windows:
            w_point, w_ci = window_intervals(np.stack([_matrix(group, k, per_run=det) for k in windows], axis=-1))
            for j, key in enumerate(windows):
                row[f"{key}_iqm"] = _finite_or_none(w_point[j])
                row[f"{key}_ci"] = [_finite_or_none(w_ci[0, j]), _finite_or_none(w_ci[1, j])]
        means = [k for k in (TOLERANCE_KEY, "control_effort") if all(k in e for c in group for e in c["episodes"])]
        if means:
            m_point, m_ci = mean_intervals(np.stack([_matrix(group, k, per_run=det) for k in means], axis=-1))
            for j, key in enumerate(means):
                name = key if key == TOLERANCE_KEY else f"{key}_mean"
                row[name] = float(m_point[j])
                row[f"{key}_ci"] = [float(m_ci[0, j]), float(m_ci[1, j])]
        if det and all(c.get("roundoff") for c in group):
            row["roundoff_sensitivity"] = roundoff_sensitivity(group)
        timing = {k: [e[k] for c in group for e in c["episodes"] if k in e] for k in TIMING_METRICS}
        row["compute_us_per_step_median"] = float(np.median(timing[TIMING_METRICS[0]])) if timing[
            TIMING_METRICS[0]] else None
        for k in TIMING_METRICS[1:]:  # the worst episode's p99 and max
            row[k] = float(np.max(timing[k])) if timing[k] else None
        single = [c["episodes"][0].get(COMPUTE_SINGLE) for c in group]  # one figure per run
        row[COMPUTE_SINGLE] = float(np.median(single)) if all(v is not None for v in single) else None
        if all(c.get("selection") for c in group):
            row["selection"] = selection_iqms(group, per_run=det)
        ref = groups.get((task, tier, REFERENCE))
        if ref is not None and entry != REFERENCE:
            x = _matrix(group, "rms_position_error", -1.0)  # higher is better for rliable
            y = _matrix(ref, "rms_position_error", -1.0)
            n = min(x.shape[1], y.shape[1])  # an entry with fewer episodes (MPC): the first n, the same seeds
            x, y = x[:, :n], y[:, :n]
            point, ci = _seeded_interval_estimates({"p": (x, y)}, metrics.probability_of_improvement,
                                                   POI_BOOTSTRAP_REPS)
            row["prob_improvement"] = float(np.asarray(point["p"]).reshape(-1)[0])
            row["prob_improvement_ci"] = [float(v) for v in np.asarray(ci["p"]).reshape(-1)[:2]]
        rows.append(row)
    return rows


def selection_iqms(group: list[dict], per_run: bool = False) -> dict:
    """Over the selection episodes of one entry's cells: the IQM of each headline metric (:data:`WINDOWS`; a crashed
    window: None where it reaches the IQM), the crash rate, the mean ``fraction_within_1cm`` (where recorded), and
    their number per run."""
    metrics = [metric for _, metric, _ in WINDOWS]
    selection = [{**c, "episodes": c["selection"]} for c in group]
    iqm = _iqms(np.stack([_matrix(selection, k, per_run=per_run) for k in metrics], axis=-1))
    out = {"episodes": len(group[0]["selection"]), "crash_rate": float(_matrix(selection, "crashed").mean()),
           **{f"{k}_iqm": _finite_or_none(v) for k, v in zip(metrics, iqm)}}
    if all(TOLERANCE_KEY in e for c in selection for e in c["episodes"]):
        out[TOLERANCE_KEY] = float(_matrix(selection, TOLERANCE_KEY, per_run=per_run).mean())
    return out


def roundoff_sensitivity(group: list[dict]) -> dict:
    """How far each headline metric (:data:`WINDOWS`) and ``fraction_within_1cm`` of a deterministic row moves
    when its start moves by round-off-level amounts: the largest |probe - recorded| over the runs' ``roundoff``
    episodes (a probe that crashes where the recorded episode did not, or the reverse: None, unbounded)."""
    out = {}
    for key in [metric for _, metric, _ in WINDOWS] + [TOLERANCE_KEY]:
        spread = 0.0
        for c in group:
            if not all(key in e or key == WHOLE for e in [c["episodes"][0], *c["roundoff"]]):
                spread = None
                break
            base = episode_scores(c["episodes"][:1], key)[0]
            probes = episode_scores(c["roundoff"], key)
            if np.isinf(base) or np.isinf(probes).any():
                if not (np.isinf(base) and np.isinf(probes).all()):
                    spread = None
                    break
                continue
            spread = max(spread, float(np.max(np.abs(probes - base))))
        out[key] = spread
    return out


# ------------------------------------------------------------------------------------------ main
def _commit(base: Path) -> str:
    """The commit of the git checkout at ``base`` ("unknown" outside one)."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=base, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def build(root: Path = RUNS_DIR, spec: Path = SPEC_FILE, base: Path = Path("."), inference: str | None = None) -> dict:
    """The leaderboard JSON from the job results under ``root``; ``base``: where the recorded commit is read;
    ``inference``: the learned entries' forward pass (default: the spec's)."""
    s = load_spec(spec)
    cells, missing = collect(root, spec, inference=inference)
    if not cells:
        raise ConfigError(f"no results under {root}; run python baselines/run_jobs.py first")
    meta = {"command": COMMAND, "commit": _commit(base), "date": _dt.date.today().isoformat(),
            "tasks": list(s["tasks"]), "tiers": list(s["evaluation"]["tiers"]),
            "episodes": int(s["evaluation"]["episodes"]), "eval_seed": int(s["evaluation"]["seed"]),
            "test_seed": int(s["evaluation"]["seed"]), "selection_seed": selection_seed(s["evaluation"]),
            "selection_episodes": int(s["evaluation"].get("selection_episodes", 0)),
            "inference": inference or s["evaluation"].get("inference", "lean"), "min_ci_values": MIN_CI_VALUES,
            "seeds": len(s["seeds"]), "bootstrap_reps": BOOTSTRAP_REPS, "poi_bootstrap_reps": POI_BOOTSTRAP_REPS,
            "bootstrap_seed": BOOTSTRAP_SEED, "compute_pass": COMPUTE_PASS,
            "reference": REFERENCE, "missing_jobs": missing, "selection_rule": SELECTION_RULE,
            "crash_test": CRASH_TEST, "crash_alpha": CRASH_ALPHA, "tolerance_m": TOLERANCE_M,
            "roundoff_shift_m": ROUNDOFF_SHIFT_M, "version": 6}
    return {"meta": meta, "aggregates": aggregate(cells), "cells": cells}


_META_KEYS = {"command": str, "commit": str, "date": str, "tasks": list, "tiers": list, "episodes": int,
              "eval_seed": int, "seeds": int, "bootstrap_reps": int, "poi_bootstrap_reps": int}
_SEED_KEYS = ("test_seed", "selection_seed", "selection_episodes")
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
    for key in _SEED_KEYS:  # v4: the test and the selection episodes
        if key in meta and (not isinstance(meta[key], int) or isinstance(meta[key], bool)):
            bad(f"meta.{key} must be an int, got {meta[key]!r}")
    if not isinstance(data["aggregates"], list) or not isinstance(data["cells"], list):
        bad("aggregates and cells must be lists")
    non_finite = first_non_finite(data)
    if non_finite is not None:
        bad(f"{non_finite} is not a finite number")
    def number_or_none(v) -> bool:
        return v is None or number(v)

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
        for metric in (WHOLE, *WINDOW_METRICS):  # windowed rows; null: crashed (an IQM) or unbounded (a CI bound)
            if f"{metric}_iqm" not in r:
                continue
            ci = r.get(f"{metric}_ci")
            if not number_or_none(r[f"{metric}_iqm"]) or not (
                    isinstance(ci, list) and len(ci) == 2 and all(number_or_none(v) for v in ci)):
                bad(f"{where}.{metric}_iqm must be a finite number or null and {metric}_ci a list of two, got "
                    f"{r[f'{metric}_iqm']!r} and {ci!r}")
        for key in ("compute_us_per_step_median", *TIMING_METRICS[1:], COMPUTE_SINGLE):
            if not number_or_none(r.get(key)):
                bad(f"{where}.{key} must be a finite number or null")
        if "ci_values" in r and (not isinstance(r["ci_values"], int) or isinstance(r["ci_values"], bool)
                                 or r["ci_values"] < 1):
            bad(f"{where}.ci_values must be an integer >= 1, got {r['ci_values']!r}")
        if "selection" in r:
            chosen = r["selection"]
            if not isinstance(chosen, dict) or not all(number_or_none(chosen.get(f"{m}_iqm")) for _, m, _ in WINDOWS):
                bad(f"{where}.selection must be an object with a finite number or null per "
                    f"{[f'{m}_iqm' for _, m, _ in WINDOWS]}, got {chosen!r}")
        if not isinstance(r.get("deterministic", False), bool):
            bad(f"{where}.deterministic must be true or false")
        if TOLERANCE_KEY in r and not (number(r[TOLERANCE_KEY]) and 0 <= r[TOLERANCE_KEY] <= 1):
            bad(f"{where}.{TOLERANCE_KEY} must be a share in [0, 1], got {r[TOLERANCE_KEY]!r}")
        for key in ("crashes", "crash_episodes"):
            if key in r and (not isinstance(r[key], int) or isinstance(r[key], bool) or r[key] < 0):
                bad(f"{where}.{key} must be an integer >= 0, got {r[key]!r}")
    return data


def first_non_finite(value, where: str = "") -> str | None:
    """The path (``cells[3].summary.mean_return``) of the first NaN or infinity in ``value``, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return where or "the value"
    if isinstance(value, dict):
        items = ((f"{where}.{k}" if where else str(k), v) for k, v in value.items())
    elif isinstance(value, list):
        items = ((f"{where}[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for w, v in items:
        found = first_non_finite(v, w)
        if found is not None:
            return found
    return None


def read_data(path: Path) -> dict:
    if path.is_dir():
        raise ConfigError(f"--json {path} is a directory; expected the leaderboard JSON file")
    if not path.is_file():
        raise ConfigError(f"no leaderboard JSON at {path}")
    try:
        data = loads_json(path.read_text(encoding="utf-8"), str(path))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"leaderboard JSON {path} is not valid JSON ({exc}); re-create it with python "
                          f"baselines/leaderboard.py") from None
    return validate_data(data, str(path))
