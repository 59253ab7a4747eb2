"""Issue 23, leaderboard v3: statistics per window with the crashed-window rule, the CI rule for identical
episodes, the per-window headline (learned vs model-based), the spec's analytic kinds (passivity, mpc) with their
own episode counts, and re-scoring stale results without training."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EPISODE_METRICS
from softpvtol_gym.baselines.leaderboard.jobs import (
    Job,
    analytic_policy,
    load_jobs,
    run_job,
    stale_evaluations,
    stale_jobs,
)
from softpvtol_gym.baselines.leaderboard.stats import (
    _matrix,
    _seeded_interval_estimates,
    _three_metrics,
    aggregate,
    validate_data,
    window_headline,
)

STEADY = "rms_position_error_steady"


def ep(v: float, crashed: bool = False, steady: float | None = "same", ret: float = 100.0) -> dict:
    """An episode whose errors are all ``v`` (its last half ``steady``; None: crashed there)."""
    steady = v if steady == "same" else steady
    e = {k: v for k in EPISODE_METRICS} | {"return": ret, "crashed": crashed, "length": 100,
                                           STEADY: None if crashed else steady,
                                           "max_position_error_final_5s": None if crashed else v}
    return e | {"compute_us_per_step": 12.0, "compute_us_per_step_p99": 20.0, "compute_us_per_step_max": 900.0}


def cell(entry: str, seed: int, episodes: list[dict], policy: str = "ppo") -> dict:
    return {"task": "track_paper", "tier": "nominal", "entry": entry, "policy": policy, "action_mode": "residual",
            "train_task": "track_paper", "train_tier": None if policy != "ppo" else "nominal", "seed": seed,
            "episodes": episodes}


# --------------------------------------------------------------------------------- statistics
def test_an_analytic_entry_with_identical_episodes_has_one_value_and_a_ci_of_zero_width():
    (row,) = aggregate([cell("passivity-bounded", 0, [ep(1.868)] * 20, policy="passivity-bounded")])
    assert row["deterministic"] and row["ci_over"].startswith("none")
    for key in ("rms_position_error", STEADY, "rms_position_error_transient", "max_position_error_final_5s"):
        assert row[f"{key}_iqm"] == pytest.approx(1.868) and row[f"{key}_ci"] == [pytest.approx(1.868)] * 2, key
    assert row["crash_rate"] == 0.0 and row["compute_us_per_step_median"] == 12.0
    assert (row["compute_us_per_step_p99"], row["compute_us_per_step_max"]) == (20.0, 900.0)


def test_a_learned_entry_with_identical_episodes_gets_its_ci_from_the_training_seeds_only():
    values = [1.30, 1.35, 1.40, 1.50, 1.60]
    cells = [cell("PPO", s, [ep(v)] * 20) for s, v in enumerate(values)]
    (row,) = aggregate(cells)
    assert row["deterministic"] and row["ci_over"] == "training seeds only (a deterministic task and tier)"
    assert row["rms_position_error_iqm"] == pytest.approx(stats.trim_mean(values, 0.25))  # 1.35, 1.40, 1.50
    seeds_only = np.stack([_matrix(cells, k, per_run=True) for k in ("rms_position_error", "return", "crashed")],
                          axis=-1)
    _, ci = _seeded_interval_estimates({"x": seeds_only}, _three_metrics, 2000)
    assert row["rms_position_error_ci"] == pytest.approx(list(ci["x"][:, 0]))
    # the runs x episodes bootstrap of the 20 copies would claim a narrower CI: the rule widens it
    every = np.stack([_matrix(cells, k) for k in ("rms_position_error", "return", "crashed")], axis=-1)
    _, narrow = _seeded_interval_estimates({"x": every}, _three_metrics, 2000)
    assert narrow["x"][1, 0] - narrow["x"][0, 0] < row["rms_position_error_ci"][1] - row["rms_position_error_ci"][0]
    lo, hi = row[f"{STEADY}_ci"]
    assert min(values) <= lo <= row[f"{STEADY}_iqm"] <= hi <= max(values)
    # one run whose episodes differ: no longer deterministic on its own, every episode counts
    cells[2] = cell("PPO", 2, [ep(1.40), ep(1.41)] * 10)
    (row,) = aggregate(cells)
    assert not row["deterministic"] and row["ci_over"] == "runs and episodes"
    # unless an analytic entry shows the task and tier are deterministic: the episodes of that run differ by
    # numerical noise only, and count once, as their mean
    rows = aggregate(cells + [cell("passivity-bounded", 0, [ep(1.868)] * 20, policy="passivity-bounded")])
    row = next(r for r in rows if r["entry"] == "PPO")
    assert row["deterministic"] and row["rms_position_error_iqm"] == pytest.approx(
        stats.trim_mean([1.30, 1.35, 1.405, 1.50, 1.60], 0.25))


def test_crashed_windows_count_as_worse_than_any_value_not_as_missing():
    finite = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    eps = [ep(v) for v in finite] + [ep(0.05, crashed=True)]
    (row,) = aggregate([cell("PPO", 0, eps)])
    # 8 episodes: the IQM trims 2 at each end; the crashed one is the worst, so the middle is 0.3 .. 0.6
    assert row[f"{STEADY}_iqm"] == pytest.approx(np.mean([0.3, 0.4, 0.5, 0.6]))
    assert row[f"{STEADY}_iqm"] > stats.trim_mean(finite, 0.25)  # dropping the crash would look better
    assert row["rms_position_error_iqm"] == pytest.approx(stats.trim_mean([0.05] + finite, 0.25))  # as in v2
    assert row["crash_rate"] == pytest.approx(1 / 8)
    # three of eight crashed: the interquartile range reaches crashed windows
    eps = [ep(v) for v in finite[:5]] + [ep(0.05, crashed=True)] * 3
    (row,) = aggregate([cell("PPO", 0, eps)])
    assert row[f"{STEADY}_iqm"] is None and row[f"{STEADY}_ci"][1] is None
    assert row["rms_position_error_iqm"] is not None and row["crash_rate"] == pytest.approx(3 / 8)
    data = {"meta": {"command": "x", "commit": "x", "date": "x", "tasks": ["track_paper"], "tiers": ["nominal"],
                     "episodes": 8, "eval_seed": 1_000_000, "seeds": 1, "bootstrap_reps": 2000,
                     "poi_bootstrap_reps": 300}, "aggregates": [row], "cells": []}
    assert validate_data(data, "test") is data  # null is a valid window statistic
    row[f"{STEADY}_iqm"] = float("nan")
    with pytest.raises(ConfigError, match="not a finite number"):
        validate_data(data, "test")


def _row(entry, policy, steady, ci, crash=0.0, whole=1.0):
    return {"task": "hover", "tier": "wind", "entry": entry, "policy": policy, "crash_rate": crash,
            "rms_position_error_iqm": whole, "rms_position_error_ci": [whole - 0.1, whole + 0.1],
            f"{STEADY}_iqm": steady, f"{STEADY}_ci": ci}


def test_the_headline_compares_the_strongest_learned_and_model_based_entry_per_window():
    meta = {"tasks": ["hover"], "tiers": ["wind"]}

    def verdicts(rows):
        return {r["window"]: (r["winner"], r["model_based"]["entry"], r["learned"]["entry"])
                for r in window_headline({"meta": meta, "aggregates": rows})}

    rows = [_row("passivity-bounded", "passivity-bounded", 0.6, [0.5, 0.7]),
            _row("passivity-integral", "passivity-integral", 0.01, [0.008, 0.012], whole=0.9),
            _row("PPO-a", "ppo", 0.02, [0.015, 0.03], whole=0.2),
            _row("PPO-b", "ppo", None, [0.5, None], crash=0.2, whole=0.1)]  # crashes: never the strongest there
    v = verdicts(rows)
    assert v["steady"] == ("model-based", "passivity-integral", "PPO-a")
    assert v["whole"][0] == "neither"  # PPO-b is lower but crashes more; its CI is below: no clear winner
    rows[1][f"{STEADY}_ci"] = [0.008, 0.016]  # overlapping CIs
    assert verdicts(rows)["steady"][0] == "neither"
    rows = [r for r in rows if r["entry"] != "PPO-b"]
    assert verdicts(rows)["whole"] == ("learned", "passivity-integral", "PPO-a")
    assert "transient" not in verdicts(rows)  # rows without a window's statistics leave it out


# ---------------------------------------------------------------------------------------- spec
HEAD = "evaluation: {episodes: 20, seed: 1000000, tiers: [nominal, model_gap]}\ntasks: [hover]\ntrained: []\n" \
       "seeds: [0]\n"


def _spec(tmp_path, analytic: str):
    path = tmp_path / "spec.yml"
    path.write_text(HEAD + f"analytic: {analytic}\n")
    return path


def test_analytic_entries_of_each_kind_become_jobs_with_their_own_episode_counts(tmp_path):
    jobs = load_jobs(_spec(tmp_path, "[{name: passivity-bounded, kind: passivity, allocation: exact, loop: bounded}, "
                                     "{name: mpc, kind: mpc, episodes: 5, options: {horizon: 20, weights: [1, 2]}}]"))
    bounded, mpc = jobs
    assert (bounded.kind, bounded.loop, bounded.eval_episodes) == ("passivity", "bounded", 20)
    assert (mpc.kind, mpc.eval_episodes, mpc.name) == ("mpc", 5, "mpc_hover")
    assert mpc.options == (("horizon", 20), ("weights", (1, 2))) and mpc.eval_tiers == ("nominal", "model_gap")
    # the shipped spec (leaderboard v3) is valid and lists every analytic kind
    shipped = load_jobs()
    assert {j.kind for j in shipped if not j.learned} == {"passivity", "mpc"}
    assert "model_gap" in shipped[0].eval_tiers
    assert next(j for j in shipped if j.kind == "mpc").eval_episodes < shipped[0].eval_episodes


@pytest.mark.parametrize("analytic, message", [
    ("[{name: m, kind: mpc, episodes: 0}]", r"analytic\[0\]\.episodes must be an integer in \[1, 10,000\]"),
    ("[{name: m, kind: mpc, episodes: 10001}]", r"analytic\[0\]\.episodes must be an integer"),
    ("[{name: m, kind: mpc, episodes: '5'}]", r"analytic\[0\]\.episodes must be an integer"),
    ("[{name: m, kind: mpc, episodes: true}]", r"analytic\[0\]\.episodes must be an integer"),
    ("[{name: m, kind: mpc, episodes: 2.5}]", r"analytic\[0\]\.episodes must be an integer"),
    ("[{name: m, kind: lqr}]", r"analytic\[0\]\.kind must be one of \['passivity', 'mpc'\], got 'lqr'"),
    ("[{name: m}]", r"analytic\[0\] lacks the keys \['kind'\]"),
    ("[{name: m, kind: mpc, loop: bounded}]", r"\(kind mpc\) has keys \['loop'\] that only other kinds take"),
    ("[{name: p, kind: passivity, allocation: exact, options: {a: 1}}]", r"\(kind passivity\) has keys \['options'\]"),
    ("[{name: p, kind: passivity}]", r"\(kind passivity\) lacks the keys \['allocation'\]"),
    ("[{name: p, kind: passivity, allocation: exact, loop: nope}]", r"analytic\[0\]\.loop .* must be one of"),
    ("[{name: m, kind: mpc, options: [1]}]", r"options must be a mapping of option names"),
    ("[{name: m, kind: mpc, options: {horizon: {a: 1}}}]", r"options\.horizon must be a number"),
    ("[{name: m, kind: mpc, colour: red}]", r"analytic\[0\] has unknown keys \['colour'\]"),
    ("[{name: ppo, kind: mpc}]", r"is taken"),
    ("[{name: m, kind: mpc}, {name: m, kind: mpc}]", r"analytic\[1\]\.name 'm' is taken"),
    ("{name: m, kind: mpc}", r"analytic must be a list"),
])
def test_bad_analytic_entries_are_refused_naming_the_key(tmp_path, analytic, message):
    with pytest.raises(ConfigError, match=message):
        load_jobs(_spec(tmp_path, analytic))


def test_the_older_passivity_list_still_works_and_shares_the_names(tmp_path):
    path = tmp_path / "spec.yml"
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact, episodes: 3}]\n"
                           "analytic: [{name: p, kind: mpc}]\n")
    with pytest.raises(ConfigError, match=r"analytic\[0\]\.name 'p' is taken"):
        load_jobs(path)
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact, episodes: 3}]\n")
    (job,) = load_jobs(path)
    assert (job.kind, job.loop, job.eval_episodes) == ("passivity", "exact", 3)
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact, kind: mpc}]\n")
    with pytest.raises(ConfigError, match=r"passivity\[0\] has unknown keys \['kind'\]"):
        load_jobs(path)


def test_an_mpc_job_without_the_mpc_extra_fails_with_a_clear_error(monkeypatch):
    from softpvtol_gym.control.mpc import _casadi

    def missing(name, *args, **kwargs):
        raise ImportError(f"No module named {name!r}")

    monkeypatch.setattr(_casadi.importlib, "import_module", missing)
    job = Job(policy="mpc", action_mode="actuators", task="hover", train_tier=None, seed=0, eval_tiers=("nominal",),
              eval_episodes=1, eval_seed=1_000_000, kind="mpc")
    with pytest.raises(ConfigError, match=r"job mpc_hover: the nonlinear MPC .* needs CasADi .*softpvtol-gym\[mpc\]"):
        analytic_policy(job)


# ------------------------------------------------------------------------------------- re-scoring
def _learned_job(**kw) -> Job:
    return Job(**{"policy": "ppo", "action_mode": "residual", "task": "hover", "train_tier": "nominal", "seed": 0,
                  "eval_tiers": ("nominal", "model_gap"), "eval_episodes": 2, "eval_seed": 1_000_000,
                  "timesteps": 64, **kw})


def test_results_without_the_windowed_metrics_a_tier_or_the_episode_count_are_stale(tmp_path):
    job = _learned_job()
    fresh = [ep(0.1), ep(0.2)]
    v2 = [{k: v for k, v in e.items() if k in ("return", "rms_position_error", "rms_attitude_error",
                                                "control_effort", "crashed", "length")} for e in fresh]
    record = {"job": dataclasses.asdict(job), "eval": {"nominal": fresh, "model_gap": fresh}}
    assert stale_evaluations(job, record) == []
    assert stale_evaluations(job, record | {"eval": {"nominal": fresh}}) == [("hover", "model_gap")]
    assert stale_evaluations(job, record | {"eval": {"nominal": v2, "model_gap": fresh}}) == [("hover", "nominal")]
    assert stale_evaluations(job, record | {"eval": {"nominal": fresh * 2, "model_gap": fresh}}) == [
        ("hover", "nominal")]
    # stale_jobs: a job with a stale result is re-scored, one without a result is left to a plain run
    import json

    other = _learned_job(seed=1)
    job.folder(tmp_path).mkdir(parents=True)
    (job.folder(tmp_path) / "eval.json").write_text(json.dumps(
        {"job": dataclasses.asdict(job), "checkpoint": None, "train_seconds": None, "eval": {"nominal": v2}}))
    assert stale_jobs([job, other], tmp_path) == ([job], [other])


def test_rescoring_never_trains(tmp_path):
    with pytest.raises(ConfigError, match="re-scoring never trains"):
        run_job(_learned_job(), tmp_path, train_missing=False)
    assert not any(tmp_path.rglob("*.run"))  # no training folder was made
