"""Distilled cells of the leaderboard: students of an analytic controller (``softpvtol distill``) trained by
behaviour cloning and DAgger, then evaluated like every learned entry.

A spec's ``distilled`` list holds one mapping per cell::

    - {teacher: integral, task: track_random, tier: nominal, variant: small, also_evaluated_on: [track_paper],
       options: {net_arch: [64, 64], precision_scale: 1.0e-3, epochs: 60}}

``teacher`` (a name of :data:`~softpvtol_gym.baselines.training.teachers.TEACHERS`), ``task`` and ``tier`` (the
tier the student's episodes fly) are required; ``variant`` (a slug) tells two cells of the same teacher, task and
tier apart; ``options`` are :class:`~softpvtol_gym.baselines.training.distill.DistillConfig` fields other than
``teacher``, ``task``, ``tiers`` and ``seed`` (the job's seed is the run's), and ``also_tiers``: the tiers the
episodes fly besides ``tier`` (a mixture: DistillConfig's ``tiers`` is ``tier`` and then these). The spec's checks
are in :mod:`~softpvtol_gym.baselines.leaderboard.spec`. Each seed of the spec is one job
(:mod:`~softpvtol_gym.baselines.leaderboard.jobs`): the student is distilled in ``<job>.run/`` and its model
files, ``distill.json`` and ``distill_config.json`` are copied into the job's folder. :func:`rounds_table` and
:func:`ablation_table` are the docs' tables of the students (``softpvtol leaderboard`` writes them).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.distill import DISTILL_FILE, DistillConfig, distill
from softpvtol_gym.baselines.util.safe_load import loads_json

#: the DistillConfig fields a cell fixes itself (an entry's ``options`` may not set them)
FIXED_FIELDS = ("teacher", "task", "tiers", "seed")
#: the option that adds tiers to a cell's own (DistillConfig's ``tiers``: the cell's ``tier``, then these)
ALSO_TIERS = "also_tiers"
#: what a distilled job's folder keeps besides the model files
RECORD_FILES = (DISTILL_FILE, "distill_config.json")


def option_fields() -> tuple:
    """The DistillConfig fields an entry's ``options`` may set."""
    return (*(f.name for f in dataclasses.fields(DistillConfig) if f.name not in FIXED_FIELDS), ALSO_TIERS)


def distill_config(teacher: str, task: str, tier: str, seed: int, options) -> DistillConfig:
    """The DistillConfig of one distilled job (ConfigError naming the option that is wrong)."""
    options = dict(options)
    unknown = [k for k in options if k not in option_fields()]
    if unknown:
        raise ConfigError(f"options {unknown} are not distillation settings; valid ones are {list(option_fields())}")
    options = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
    also = options.pop(ALSO_TIERS, ())
    if isinstance(also, (str, bytes)) or not hasattr(also, "__iter__"):
        raise ConfigError(f"options.{ALSO_TIERS} must be a list of tiers flown besides {tier!r}, got {also!r}")
    return DistillConfig(teacher=teacher, task=task, tiers=(tier, *also), seed=seed, **options)


def train_distilled(job, run_dir: Path) -> float:
    """Distil ``job``'s student in ``run_dir`` (resumed where a run was interrupted); returns its seconds."""
    config = distill_config(job.teacher, job.task, job.train_tier, job.seed, job.distill_options)
    return float(distill(config, run_dir, resume=True)["record"]["seconds"])


def student_fields(job: dict) -> dict:
    """What a job's record (``eval.json``'s ``job``) adds to its leaderboard rows: ``"privileged": True`` for the
    student of a privileged teacher, ``"trained_on"`` (its tasks and how many tiers) for a student of a mixture;
    {} for every other job."""
    pairs = (job.get("distill_options") or []) if job.get("policy") == "distilled" else []
    options = {p[0]: p[1] for p in pairs if isinstance(p, (list, tuple)) and len(p) == 2 and isinstance(p[0], str)}
    out = {"privileged": True} if options.get("privileged") is True else {}
    tiers, tasks = list(options.get(ALSO_TIERS) or []), list(options.get("also_tasks") or [])
    if tiers or tasks:
        out["trained_on"] = f"{' + '.join([job['task'], *tasks])}, {1 + len(tiers)} tiers"
    return out


def recorded_seconds(out: Path) -> float | None:
    """The distillation's seconds as its ``distill.json`` in ``out`` records them (None where it does not)."""
    try:
        path = Path(out) / DISTILL_FILE
        seconds = loads_json(path.read_text(), str(path)).get("seconds")
    except (OSError, ValueError, AttributeError):
        return None
    return float(seconds) if isinstance(seconds, (int, float)) and not isinstance(seconds, bool) else None


# ------------------------------------------------------------------------------- rounds, over seeds
#: the windows of the rounds table: (distill.json summary key, column)
ROUND_WINDOWS = (("mean_rms_position_error_transient", "first quarter [m]"),
                 ("mean_rms_position_error_steady", "last half [m]"),
                 ("mean_max_position_error_final_5s", "max last 5 s [m]"))
#: the rounds table's block in docs/baselines.md: (name, source)
ROUNDS_BLOCK = ("leaderboard.py distilled rounds", "results/leaderboard_runs/distilled-*/seed_*/distill.json")


def rounds_table(records: dict[str, list[dict]]) -> str:
    """A Markdown table of the distilled cells round by round: per cell (``records``: cell name -> the seeds'
    ``distill.json`` records) and round, the median over the seeds of each seed's mean student error per window on
    its evaluation episodes (seeds whose student crashed in that window left out), and the crashed episodes of all
    seeds; below each cell, its teacher's on the same episodes. A cell evaluated on several tasks or tiers (a
    mixture) shows its last round only."""
    def cell_values(summaries: list[dict]) -> str:
        out = []
        for key, _ in ROUND_WINDOWS:
            flown = [s[key] for s in summaries if s.get(key) is not None]
            out.append("crashed" if not flown else f"{float(np.median(flown)):.2e}"
                       + ("" if len(flown) == len(summaries) else f" ({len(flown)} seeds)"))
        crashed = sum(round(s["crash_rate"] * s["episodes"]) for s in summaries)
        return " | ".join(out) + f" | {crashed}/{sum(s['episodes'] for s in summaries)}"

    lines = ["| cell | round | samples (all rounds, median) | tier | policy | "
             + " | ".join(c for _, c in ROUND_WINDOWS) + " | crashes |",
             "|---|---|---|---|---|---|---|---|---|"]
    for cell, recs in records.items():
        first = recs[0]
        rounds = list(enumerate(first["rounds"]))
        for k, r in rounds if len(first["rounds"][0]["evaluation"]) == 1 else rounds[-1:]:  # a mixture: its last
            samples = int(np.median([rec["rounds"][k]["aggregate"] for rec in recs]))
            for tier in r["evaluation"]:
                students = [rec["rounds"][k]["evaluation"][tier]["student"] for rec in recs]
                lines.append(f"| {cell} | {k} ({r['kind']}) | {samples:,} | {tier} | student ({len(recs)} seeds) | "
                             f"{cell_values(students)} |")
        for tier in first["rounds"][0]["evaluation"]:
            teachers = [rec["rounds"][0]["evaluation"][tier]["teacher"] for rec in recs]
            lines.append(f"| {cell} | | | {tier} | teacher ({first['config']['teacher']}) | {cell_values(teachers)} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ ablation
#: the ablation table's block in docs/baselines.md: (name, source)
ABLATION_BLOCK = ("leaderboard.py distilled ablation", "results/leaderboard.json")
#: the ablation's rows from the leaderboard (track_random, nominal): (what, entry)
ABLATION_ENTRIES = (
    ("+ 3 DAgger rounds, 64 x 64", "distilled integral small (trained on nominal)"),
    ("+ 3 DAgger rounds, 256 x 256", "distilled integral (trained on nominal)"),
    ("64 x 64, observing the integrals as the teacher integrates them",
     "distilled integral small-matched (trained on nominal)"),
    ("+ PPO fine-tuning of the 64 x 64 students (2M steps: precision reward, imitation term)",
     "PPO student-finetune (trained on nominal)"),
    ("+ PPO fine-tuning of the small-matched students on the hard tier (2M steps, the same recipe)",
     "PPO student-finetune (trained on hard)"),
    ("small-matched students with a history: their last 4 observations (a frame stack)",
     "distilled integral small-matched-history (trained on nominal)"),
    ("+ PPO fine-tuning of the history students on the hard tier (2M steps, the same recipe)",
     "PPO student-history-finetune (trained on hard)"),
    ("+ PPO fine-tuning of the history students on model_gap (2M steps, the same recipe)",
     "PPO student-history-finetune (trained on model_gap)"),
    ("students of the MPC, 64 x 64 (5 rounds of 32 episodes, the teacher acting at a step with probability 0.5^k)",
     "distilled mpc small (trained on nominal)"),
    ("robust students of the MPC, 256 x 256: privileged teacher, DAgger on hover and track_random and 5 tiers, turned "
     "starts, history 4 (5 rounds of 8 episodes per task and tier)",
     "distilled mpc robust (trained on track_random + hover, 5 tiers)"),
    ("the same students as a bounded residual on the integral loop's command clipped to the actuator box (at most a "
     "quarter of the actuator half-ranges)", "distilled mpc robust-bounded (trained on track_random + hover, 5 tiers)"),
    ("the same bounded students at 64 x 64",
     "distilled mpc robust-bounded-small (trained on track_random + hover, 5 tiers)"),
    ("the teacher", "passivity-integral"),
    ("the MPC", "mpc"),
)
_WINDOW_KEYS = ("rms_position_error", "rms_position_error_transient", "rms_position_error_steady",
                "max_position_error_final_5s")


def ablation_table(aggregates: list[dict], records: dict[str, list[dict]], runs: dict[str, list[dict]]) -> str:
    """The distillation ablation on track_random nominal: behaviour cloning alone (``records``: the students'
    ``distill.json``, round 0 on their evaluation episodes), the DAgger students, the fine-tuned students and the
    teacher (``aggregates``: the leaderboard's rows, IQM on its test episodes), and the fine-tuning with and
    without the precision reward (``runs``: name -> a run's periodic evaluations, its last one)."""
    def fmt(v) -> str:
        return "crashed" if v is None else f"{v:.2e}"

    lines = ["| step | entry | whole [m] | first quarter [m] | last half [m] | max last 5 s [m] | crashes | "
             "µs/robot | episodes |", "|---|---|---|---|---|---|---|---|---|"]
    cloned = [rec["rounds"][0]["evaluation"]["nominal"]["student"] for recs in records.values() for rec in recs]
    if cloned:
        crashed = sum(round(s["crash_rate"] * s["episodes"]) for s in cloned)
        lines.append(f"| behaviour cloning only (round 0) | every distilled student | | | | | "
                     f"{crashed}/{sum(s['episodes'] for s in cloned)} | | their distillations' evaluations |")
    here = {r["entry"]: r for r in aggregates if r["task"] == "track_random" and r["tier"] == "nominal"}
    for what, entry in ABLATION_ENTRIES:
        r = here.get(entry)
        if r is None:
            continue
        values = " | ".join(fmt(r.get(f"{k}_iqm")) for k in _WINDOW_KEYS)
        single = r.get("compute_us_single")
        lines.append(f"| {what} | {entry} | {values} | {r['crash_rate']:.0%} | "
                     f"{'' if single is None else f'{single:.1f}'} | {r['runs']} x {r['episodes']} (IQM) |")
    for what, name in (("fine-tuning without the precision reward (seed 0)", "noreward"),
                       ("the same with it (seed 0)", "reward")):
        if name in runs:
            last = runs[name][-1]
            values = " | ".join(fmt(last.get(f"mean_{k}")) for k in _WINDOW_KEYS)
            lines.append(f"| {what} | finetune_reward/{name}, {last['step']:,} steps | {values} | "
                         f"{last['crash_rate']:.0%} | | {last['episodes']} (mean, its periodic evaluation) |")
    return "\n".join(lines)
