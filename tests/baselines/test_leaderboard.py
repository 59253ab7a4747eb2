"""The leaderboard: the committed one and its rules.

* docs/leaderboard.md re-renders identically from its JSON, the JSON's statistics match its per-episode data,
  and every committed checkpoint loads and reproduces, on its training tier, the episodes the leaderboard was
  computed from (so re-evaluating it lands on the leaderboard's numbers, inside its CIs).
* Statistics per window with the crashed-window rule, the CI rule for identical episodes, the per-window
  headline (learned vs model-based), the spec's analytic kinds (passivity, mpc) with their own episode counts,
  and re-scoring stale results without training.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import EPISODE_METRICS, run_episodes
from softpvtol_gym.baselines.leaderboard.episodes import analytic_policy
from softpvtol_gym.baselines.leaderboard.headline import window_headline
from softpvtol_gym.baselines.leaderboard.jobs import (
    Job,
    load_jobs,
    run_job,
    stale_evaluations,
    stale_jobs,
)
from softpvtol_gym.baselines.leaderboard.render import fmt_window, render_chart, render_markdown
from softpvtol_gym.baselines.leaderboard.stats import (
    WHOLE,
    _matrix,
    _seeded_interval_estimates,
    _three_metrics,
    aggregate,
    validate_data,
)
from tests.conftest import LAYOUT, LEADERBOARD_JSON

ROOT = Path(__file__).resolve().parents[2]
DATA = json.loads(LEADERBOARD_JSON.read_text())
LEADERBOARD_MD = LAYOUT.doc("leaderboard.md")
CHART_PNG = LAYOUT.results / "leaderboard.png"
# (checkpoint, training tier, evaluated task): every committed model on its training tier, on its own task
# and on each task it is also evaluated on (a track_random cell scored on track_paper)
LEARNED = sorted({(c["checkpoint"], c["train_tier"], c["task"]) for c in DATA["cells"] if c["checkpoint"]})


def test_markdown_regenerates_identically_from_the_committed_json():
    assert render_markdown(DATA) == LEADERBOARD_MD.read_text()


def test_chart_renders(tmp_path):
    render_chart(DATA, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 10_000 and CHART_PNG.is_file()


def test_every_job_of_the_spec_is_in_the_leaderboard():
    assert DATA["meta"]["missing_jobs"] == []
    names = {(c["policy"], c["action_mode"], c["task"], c["train_tier"], c["seed"]) for c in DATA["cells"]}
    for job in load_jobs():
        assert (job.policy, job.action_mode, job.task, job.train_tier, job.seed) in names


def test_headline_is_the_best_learned_policy_on_both_tracking_tasks():
    from softpvtol_gym.baselines.leaderboard.headline import HEADLINE_TASKS, headline
    from softpvtol_gym.baselines.leaderboard.spec import is_learned

    h = headline(DATA)
    assert h is not None and len(h["rows"]) == len(HEADLINE_TASKS) * len(DATA["meta"]["tiers"])
    keys = {(r["learned"]["action_mode"], r["learned"]["train_task"], r["learned"]["train_tier"]) for r in h["rows"]}
    assert len(keys) == 1  # one policy for every (task, tier)
    for r in h["rows"]:
        analytic = [a for a in DATA["aggregates"] if (a["task"], a["tier"]) == (r["task"], r["tier"])
                    and not is_learned(a["policy"])]
        assert r["analytic"]["rms_position_error_iqm"] == min(a["rms_position_error_iqm"] for a in analytic)
        assert r["lower"] == (r["learned"]["rms_position_error_iqm"] < r["analytic"]["rms_position_error_iqm"])
        assert r["disjoint"] == (r["learned"]["rms_position_error_ci"][1] < r["analytic"]["rms_position_error_ci"][0])


def test_trained_cells_have_at_least_five_seeds():
    seeds: dict = {}
    for c in DATA["cells"]:
        if c["policy"] == "ppo":
            seeds.setdefault((c["action_mode"], c["task"], c["train_tier"], c["tier"]), set()).add(c["seed"])
    assert seeds and all(len(s) >= 5 for s in seeds.values())


def test_statistics_match_the_per_episode_data():
    groups: dict = {}
    for c in DATA["cells"]:
        groups.setdefault((c["task"], c["tier"], c["entry"]), []).append(c)
    assert len(groups) == len(DATA["aggregates"])
    from softpvtol_gym.baselines.evaluation import WINDOW_METRICS, window_scores
    from softpvtol_gym.baselines.leaderboard.stats import deterministic_pairs

    fixed = deterministic_pairs(DATA["cells"])
    for row in DATA["aggregates"]:
        cells = groups[(row["task"], row["tier"], row["entry"])]
        if DATA["meta"].get("version", 2) >= 3:  # v3: a deterministic task and tier counts each run once
            assert row["deterministic"] == ((row["task"], row["tier"]) in fixed)

        def values(key, row=row, cells=cells):
            if row.get("deterministic"):  # each run's mean over its episodes
                return [np.mean(window_scores(c["episodes"], key)) for c in cells]
            return [v for c in cells for v in window_scores(c["episodes"], key)]

        for key in WINDOW_METRICS:
            if f"{key}_iqm" in row:
                want = stats.trim_mean(values(key), 0.25)
                assert (row[f"{key}_iqm"] is None) if not np.isfinite(want) else \
                    row[f"{key}_iqm"] == pytest.approx(want, rel=1e-12)
        eps = [e for c in cells for e in c["episodes"]]
        if row.get("deterministic"):
            iqm = stats.trim_mean([np.mean([e["rms_position_error"] for e in c["episodes"]]) for c in cells], 0.25)
        else:
            iqm = stats.trim_mean([e["rms_position_error"] for e in eps], 0.25)
        crash = np.mean([e["crashed"] for e in eps])
        assert row["runs"] == len(cells)
        assert row["rms_position_error_iqm"] == pytest.approx(iqm, rel=1e-12)
        assert row["crash_rate"] == pytest.approx(crash, abs=1e-12)
        lo, hi = row["rms_position_error_ci"]
        assert lo <= row["rms_position_error_iqm"] <= hi
        if "prob_improvement" in row:
            lo, hi = row["prob_improvement_ci"]
            assert 0.0 <= lo <= row["prob_improvement"] <= hi <= 1.0


# The replays below compare with the leaderboard's episodes to the last bit. The leaderboard scores learned entries
# with the lean inference path (meta "inference": "lean"): a float64 forward pass per observation row, compiled by
# numba without fastmath, so an episode's actions depend neither on the batch it runs in nor on the CPU's float32
# matrix kernels (the torch path's float32 GEMM sums in an order that depends on both, and a closed loop carries
# such last-bit differences along: `python benchmarks/replay_drift.py --inference torch` measures that drift).
# Sub-env i of a batch seeded s runs episode s + i, so the first REPLAYED_EPISODES episodes of each cell are
# replayed alone and must equal the committed ones exactly.
REPLAYED_KEYS = ("return", "rms_position_error", "rms_attitude_error", "control_effort", "rms_position_error_steady",
                 "max_position_error_final_5s")
#: episodes replayed per committed checkpoint and task (the first ones of the cell's batch)
REPLAYED_EPISODES = 4


def _replay(checkpoint: str, train_tier: str, task: str) -> tuple[list[dict], dict]:
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    assert DATA["meta"]["inference"] == "lean"
    path = ROOT / checkpoint
    assert path.is_file() and path.stat().st_size < 1_000_000
    policy, config = LearnedPolicy.load(path, inference="lean")
    cell = next(c for c in DATA["cells"] if c["checkpoint"] == checkpoint and c["tier"] == train_tier
                and c["task"] == task)
    assert (config.task, config.tier) == (cell.get("train_task", task), train_tier)
    # on the base loop it was trained on
    episodes = run_episodes(policy, config.action_mode, task, train_tier, REPLAYED_EPISODES, cell["eval_seed"],
                            env_kwargs=config.eval_env_kwargs())
    return episodes, cell


#: metrics computed with numpy's sin, cos and arctan2, whose vectorised forms differ by an ulp between CPUs (with and
#: without AVX-512): equal within this relative tolerance, the others to the last bit
ULP_KEYS = {"rms_attitude_error": 1e-13}


def check_replay(got: list[dict], want: list[dict]) -> None:
    """Replayed episodes against the first ones of the leaderboard's: the same to the last bit (but for the metrics
    of :data:`ULP_KEYS`, within an ulp or two)."""
    assert len(got) == REPLAYED_EPISODES <= len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        assert (g["crashed"], g["length"]) == (w["crashed"], w["length"]), f"episode {i}"
        for key in REPLAYED_KEYS:
            if key in ULP_KEYS:
                assert g[key] == pytest.approx(w[key], rel=ULP_KEYS[key], abs=0.0), f"episode {i}: {key}"
            else:
                assert g[key] == w[key], f"episode {i}: {key} {g[key]!r} != {w[key]!r}"


@pytest.mark.slow  # one short replay per committed checkpoint and evaluated task (about 120), ~1 min
@pytest.mark.parametrize(
    "checkpoint, train_tier, task", LEARNED, ids=[c[0].split("leaderboard_runs/")[-1] for c in LEARNED]
)
def test_committed_checkpoint_reproduces_its_leaderboard_episodes(checkpoint, train_tier, task):
    episodes, cell = _replay(checkpoint, train_tier, task)
    check_replay(episodes, cell["episodes"])


#: analytic cells replayed against the committed leaderboard: each passivity loop on a tier with noise, wind and
#: mismatch (the MPC's: tests/baselines/test_mpc_reproduction.py, under the BLAS kernels its episodes were run with)
ANALYTIC_REPLAYS = [("passivity-paper", "track_paper", "hard"), ("passivity-bounded", "track_random", "hard"),
                    ("passivity-integral", "track_paper", "hard"), ("passivity-extended", "hover", "wind"),
                    ("passivity-exact", "track_random", "mismatch")]


def analytic_replay(entry: str, task: str, tier: str) -> tuple[list[dict], list[dict]]:
    """(the first episodes of an analytic cell run with the current code, the committed ones)."""
    from softpvtol_gym.baselines.leaderboard.jobs import load_jobs

    (job,) = [j for j in load_jobs() if j.policy == entry and j.task == task]
    cell = next(c for c in DATA["cells"] if c["entry"] == entry and c["task"] == task and c["tier"] == tier)
    policy, env_kwargs = analytic_policy(job)
    got = run_episodes(policy, job.action_mode, task, tier, REPLAYED_EPISODES, cell["eval_seed"], env_kwargs=env_kwargs)
    return got, cell["episodes"]


@pytest.mark.slow
@pytest.mark.parametrize("entry, task, tier", ANALYTIC_REPLAYS, ids=["-".join(r) for r in ANALYTIC_REPLAYS])
def test_committed_analytic_cells_reproduce_with_the_current_code(entry, task, tier):
    """An analytic entry's committed episodes are what the current controller code gives (a change of a
    controller must re-evaluate its cells: python baselines/run_jobs.py --reevaluate --only <entry>)."""
    check_replay(*analytic_replay(entry, task, tier))


def test_jobs_run_with_any_executor_and_reevaluate_identically(tmp_path):
    """The job list is independent jobs: a thread pool stands in for a cluster engine here."""
    from concurrent.futures import ThreadPoolExecutor

    from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, reevaluate_job, run_jobs

    spec = tmp_path / "spec.yml"
    spec.write_text("evaluation: {episodes: 2, seed: 1000000, tiers: [nominal, wind]}\n"
                    "passivity: [{name: passivity-exact, allocation: exact}, "
                    "{name: passivity-paper, allocation: paper}]\n"
                    "tasks: [hover]\ntrained: []\nseeds: [0]\n")
    jobs = load_jobs(spec)
    assert [j.name for j in jobs] == ["passivity-exact_hover", "passivity-paper_hover"]
    with ThreadPoolExecutor(max_workers=2) as ex:
        done = run_jobs(jobs, ex, tmp_path / "runs")
    assert sorted(done) == sorted(j.name for j in jobs)
    from softpvtol_gym.baselines.evaluation import without_timing

    def episodes():
        rec = json.loads((tmp_path / "runs" / jobs[0].name / EVAL_FILE).read_text())
        return {tier: [without_timing(e) for e in eps] for tier, eps in rec["eval"].items()}

    first = episodes()
    assert set(first) == {"nominal", "wind"}
    reevaluate_job(jobs[0], tmp_path / "runs")
    assert episodes() == first  # all but the wall time (compute_us_per_step)


def test_bootstrap_is_reproducible():
    """rliable draws bootstrap indices from numpy's global RNG; the generator seeds it per call."""
    from softpvtol_gym.baselines.leaderboard.stats import REFERENCE, aggregate

    # the reference entry alone (its rows carry no P(better), which needs the reference's cells too)
    cells = [c for c in DATA["cells"] if c["task"] == "hover" and c["entry"] == REFERENCE]
    np.random.seed(123)
    first = aggregate(cells)
    np.random.rand(7)
    assert aggregate(cells) == first
    row = next(r for r in DATA["aggregates"] if r["task"] == "hover" and r["tier"] == "nominal"
               and r["entry"] == REFERENCE)
    again = next(r for r in first if r["tier"] == "nominal")
    assert {k: again[k] for k in row} == row  # (a v2 JSON's rows lack the v3 keys)


def _row(task, tier, entry, err, ci, crash=0.0, policy="ppo", mode="residual", train_task=None):
    return {"task": task, "tier": tier, "entry": entry, "policy": policy, "action_mode": mode,
            "train_task": train_task or task, "train_tier": "nominal", "rms_position_error_iqm": err,
            "rms_position_error_ci": ci, "crash_rate": crash, "crash_rate_ci": [crash, crash]}


def test_headline_picks_one_policy_for_every_pair_and_the_strongest_analytic_per_pair():
    from softpvtol_gym.baselines.leaderboard.headline import headline

    meta = {"tasks": ["hover", "track_paper", "track_random"], "tiers": ["nominal", "wind"]}
    rows = []
    for task in ("track_paper", "track_random"):
        for tier, (a_err, b_err) in {"nominal": (1.0, 1.2), "wind": (2.0, 1.5)}.items():
            rows += [_row(task, tier, "passivity-a", a_err, [a_err - 0.1, a_err + 0.1], policy="passivity-a"),
                     _row(task, tier, "passivity-b", b_err, [b_err - 0.1, b_err + 0.1], policy="passivity-b")]
        # a policy trained on track_random, better than either analytic controller everywhere
        rows.append(_row(task, "nominal", "PPO-residual (x)", 0.5, [0.4, 0.95], crash=0.1, train_task="track_random"))
        rows.append(_row(task, "wind", "PPO-residual (x)", 1.35, [1.3, 1.38], train_task="track_random"))
        # one that is evaluated on its own task only does not qualify, however good
        if task == "track_random":
            rows += [_row(task, t, "PPO-actuators (y)", 0.01, [0.0, 0.02], mode="actuators") for t in meta["tiers"]]
    h = headline({"meta": meta, "aggregates": rows})
    assert h["policy"] == "PPO-residual trained on track_random (nominal tier)"
    by = {(r["task"], r["tier"]): r for r in h["rows"]}
    assert set(by) == {(t, tier) for t in ("track_paper", "track_random") for tier in ("nominal", "wind")}
    assert by[("track_paper", "nominal")]["analytic"]["entry"] == "passivity-a"   # 1.0 < 1.2
    assert by[("track_paper", "wind")]["analytic"]["entry"] == "passivity-b"      # 1.5 < 2.0
    assert by[("track_paper", "nominal")]["lower"] and not by[("track_paper", "nominal")]["disjoint"]  # 0.95 > 0.9
    assert by[("track_paper", "wind")]["disjoint"] and by[("track_paper", "wind")]["crash_no_higher"]
    assert not by[("track_paper", "nominal")]["crash_no_higher"]
    # no learned policy on every pair: no headline
    assert headline({"meta": meta, "aggregates": [r for r in rows if r["entry"] != "PPO-residual (x)"]}) is None


@pytest.mark.slow  # one evaluate.py subprocess, a few hover episodes
def test_evaluate_script_reproduces_a_committed_cell(tmp_path):
    """``baselines/evaluate.py`` on a committed checkpoint gives the leaderboard's episodes to the last bit (the
    base loop from the checkpoint's config, the lean inference the leaderboard was scored with)."""
    import os
    import subprocess
    import sys

    cell = next(c for c in DATA["cells"] if c["checkpoint"] and c["task"] == "hover" and c["tier"] == "nominal"
                and c["action_mode"] == "residual" and c["train_tier"] == "nominal")
    out = tmp_path / "eval.json"
    script = ROOT / "baselines" / "evaluate.py"
    r = subprocess.run([sys.executable, str(script), "--policy", str(ROOT / cell["checkpoint"]), "--task", "hover",
                        "--tier", "nominal", "--episodes", str(REPLAYED_EPISODES), "--seed", str(cell["eval_seed"]),
                        "--json", str(out)],
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=300)
    assert r.returncode == 0, r.stderr
    check_replay(json.loads(out.read_text())["episodes"], cell["episodes"])


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


def _window_row(entry, policy, steady, ci, crash=0.0, whole=1.0, episodes=20):
    """A synthetic aggregate row on hover/wind: ``crash`` of ``episodes`` episodes crashed."""
    return {"task": "hover", "tier": "wind", "entry": entry, "policy": policy, "crash_rate": crash,
            "crashes": round(crash * episodes), "crash_episodes": episodes, "runs": 1, "episodes": episodes,
            "rms_position_error_iqm": whole, "rms_position_error_ci": [whole - 0.1, whole + 0.1],
            f"{WHOLE}_iqm": whole, f"{WHOLE}_ci": [whole - 0.1, whole + 0.1],
            f"{STEADY}_iqm": steady, f"{STEADY}_ci": ci}


def test_the_headline_compares_the_strongest_learned_and_model_based_entry_per_window():
    meta = {"tasks": ["hover"], "tiers": ["wind"]}

    def verdicts(rows):
        return {r["window"]: (r["winner"], r["model_based"]["entry"], r["learned"]["entry"], r["decided_by"])
                for r in window_headline({"meta": meta, "aggregates": rows})}

    rows = [_window_row("passivity-bounded", "passivity-bounded", 0.6, [0.5, 0.7]),
            _window_row("passivity-integral", "passivity-integral", 0.01, [0.008, 0.012], whole=0.9),
            _window_row("PPO-a", "ppo", 0.02, [0.015, 0.03], whole=0.2, episodes=100),
            _window_row("PPO-b", "ppo", None, [0.5, None], crash=0.2, whole=0.1, episodes=100)]
    v = verdicts(rows)
    assert v["steady"] == ("model-based", "passivity-integral", "PPO-a", "error")
    # PPO-b has the lowest whole-episode IQM but crashes: the fewest crashes choose PPO-a, which is lower
    assert v["whole"] == ("learned", "passivity-integral", "PPO-a", "error")
    rows[1][f"{STEADY}_ci"] = [0.008, 0.016]  # overlapping CIs
    assert verdicts(rows)["steady"][0::3] == ("neither", "overlap")
    assert "transient" not in verdicts(rows)  # rows without a window's statistics leave it out


def test_significantly_more_crashes_lose_the_cell_and_a_few_do_not():
    meta = {"tasks": ["hover"], "tiers": ["wind"]}
    mpc = _window_row("mpc", "mpc", 0.01, [0.008, 0.012], crash=0.3)  # 6 of 20
    ppo = _window_row("PPO-a", "ppo", 0.02, [0.015, 0.03], whole=0.5, crash=0.01, episodes=100)  # 1 of 100
    (steady,) = [r for r in window_headline({"meta": meta, "aggregates": [mpc, ppo]}) if r["window"] == "steady"]
    assert (steady["winner"], steady["decided_by"]) == ("learned", "crashes")
    assert steady["crash_p"]["model_based_more"] < 0.05 < steady["crash_p"]["learned_more"]
    mpc = _window_row("mpc", "mpc", 0.01, [0.008, 0.012], crash=0.05)  # 1 of 20 against 1 of 100: no evidence
    (steady,) = [r for r in window_headline({"meta": meta, "aggregates": [mpc, ppo]}) if r["window"] == "steady"]
    assert (steady["winner"], steady["decided_by"]) == ("model-based", "error")


def test_the_crash_test_is_fishers_exact_test_on_the_counts():
    from scipy.stats import fisher_exact

    from softpvtol_gym.baselines.leaderboard.headline import more_crashes

    a = {"crashes": 5, "crash_episodes": 20}
    b = {"crashes": 1, "crash_episodes": 100}
    assert more_crashes(a, b) == pytest.approx(fisher_exact([[5, 15], [1, 99]], alternative="greater").pvalue)
    assert more_crashes(b, a) == 1.0  # not even the point estimate is higher
    assert more_crashes({"crashes": 0, "crash_episodes": 20}, {"crashes": 0, "crash_episodes": 100}) == 1.0
    assert more_crashes({"crashes": 1, "crash_episodes": 20}, {"crashes": 0, "crash_episodes": 100}) > 0.05


def test_a_deterministic_cell_is_decided_only_beyond_its_roundoff_sensitivity():
    meta = {"tasks": ["hover"], "tiers": ["wind"]}
    mpc = _window_row("mpc", "mpc", 0.01, [0.01, 0.01], episodes=1) | {"deterministic": True, "ci_values": 1,
                                                                        "runs": 1}
    ppo = _window_row("PPO-a", "ppo", 0.02, [0.015, 0.03], episodes=5) | {"deterministic": True}

    def steady(rows):
        (r,) = [r for r in window_headline({"meta": meta, "aggregates": rows}) if r["window"] == "steady"]
        return r["winner"], r["decided_by"]

    assert steady([mpc, ppo]) == ("neither", "no_roundoff_probe")
    mpc["roundoff_sensitivity"] = {STEADY: 1e-4, WHOLE: 1e-4}
    assert steady([mpc, ppo]) == ("model-based", "error")
    mpc["roundoff_sensitivity"] = {STEADY: 0.05, WHOLE: 0.05}  # the start's last bits move it more than the gap
    assert steady([mpc, ppo]) == ("neither", "knife_edge")
    mpc["roundoff_sensitivity"] = {STEADY: None, WHOLE: None}  # a probe crashed where the episode did not
    assert steady([mpc, ppo]) == ("neither", "knife_edge")
    assert "(n = 1)" in fmt_window(mpc, STEADY) and "[" not in fmt_window(mpc, STEADY)


def test_the_tolerance_verdict_prefers_more_time_within_1cm():
    from softpvtol_gym.baselines.leaderboard.headline import tolerance_headline

    meta = {"tasks": ["hover"], "tiers": ["wind"]}
    rows = [_window_row("passivity-integral", "passivity-integral", 0.01, [0.008, 0.012]),
            _window_row("mpc", "mpc", 0.01, [0.008, 0.012], crash=0.1),
            _window_row("PPO-a", "ppo", 0.02, [0.015, 0.03], episodes=100)]
    for r, share, ci in zip(rows, (0.60, 0.95, 0.85), ([0.55, 0.65], [0.9, 0.97], [0.8, 0.9])):
        r |= {"fraction_within_1cm": share, "fraction_within_1cm_ci": ci,
              "selection": {"crash_rate": r["crash_rate"], "fraction_within_1cm": share}}
    (cell,) = tolerance_headline({"meta": meta, "aggregates": rows})
    # the MPC reaches the tolerance more often but crashed on the selection episodes: the integral loop is chosen
    assert (cell["model_based"]["entry"], cell["learned"]["entry"]) == ("passivity-integral", "PPO-a")
    assert (cell["winner"], cell["decided_by"]) == ("learned", "error")
    rows[2]["fraction_within_1cm_ci"] = [0.5, 0.9]
    assert tolerance_headline({"meta": meta, "aggregates": rows})[0]["winner"] == "neither"


# ---------------------------------------------------------------------------------------- spec
HEAD = "evaluation: {episodes: 20, seed: 1000000, tiers: [nominal, model_gap]}\ntasks: [hover]\ntrained: []\n" \
       "seeds: [0]\n"


def _spec(tmp_path, analytic: str):
    path = tmp_path / "spec.yml"
    path.write_text(HEAD + f"analytic: {analytic}\n")
    return path


def test_analytic_entries_of_each_kind_become_jobs_on_the_same_episodes(tmp_path):
    jobs = load_jobs(_spec(tmp_path, "[{name: passivity-bounded, kind: passivity, allocation: exact, loop: bounded}, "
                                     "{name: mpc, kind: mpc, options: {horizon: 20, weights: [1, 2]}}]"))
    bounded, mpc = jobs
    assert (bounded.kind, bounded.loop, bounded.eval_episodes) == ("passivity", "bounded", 20)
    assert (mpc.kind, mpc.eval_episodes, mpc.name) == ("mpc", 20, "mpc_hover")
    assert mpc.options == (("horizon", 20), ("weights", (1, 2))) and mpc.eval_tiers == ("nominal", "model_gap")
    # the shipped spec is valid, lists every analytic kind, and scores every entry on the same test and selection
    # episodes (the MPC included)
    shipped = load_jobs()
    assert {j.kind for j in shipped if not j.learned} == {"passivity", "mpc"}
    assert "model_gap" in shipped[0].eval_tiers
    assert {(j.eval_episodes, j.eval_seed, j.selection_episodes, j.selection_seed) for j in shipped} == {
        (20, 1_000_000, 10, 2_000_000)}
    assert {j.inference for j in shipped if j.learned} == {"lean"}


@pytest.mark.parametrize("analytic, message", [
    ("[{name: m, kind: mpc, episodes: 5}]", r"analytic\[0\]\.episodes: every entry is evaluated on the same "
                                            r"evaluation\.episodes .*got 5"),
    ("[{name: m, kind: mpc, episodes: 20}]", r"analytic\[0\]\.episodes: every entry"),
    ("[{name: p, kind: passivity, allocation: exact, episodes: 20}]", r"analytic\[0\]\.episodes: every entry"),
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
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact}]\n"
                           "analytic: [{name: p, kind: mpc}]\n")
    with pytest.raises(ConfigError, match=r"analytic\[0\]\.name 'p' is taken"):
        load_jobs(path)
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact}]\n")
    (job,) = load_jobs(path)
    assert (job.kind, job.loop, job.eval_episodes) == ("passivity", "exact", 20)
    path.write_text(HEAD + "passivity: [{name: p, allocation: exact, episodes: 3}]\n")
    with pytest.raises(ConfigError, match=r"passivity\[0\]\.episodes: every entry"):
        load_jobs(path)
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
    fresh = [ep(0.1) | {"compute_us_single": 15.0}, ep(0.2) | {"compute_us_single": 15.0}]
    v2 = [{k: v for k, v in e.items() if k in ("return", "rms_position_error", "rms_attitude_error",
                                                "control_effort", "crashed", "length")} for e in fresh]
    from softpvtol_gym.baselines.evaluation import COMPUTE_PASS

    record = {"job": dataclasses.asdict(job), "inference": "lean", "compute_pass": COMPUTE_PASS,
              "eval": {"nominal": fresh, "model_gap": fresh}}
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


def test_stale_parts_name_exactly_what_a_result_lacks():
    from softpvtol_gym.baselines.evaluation import COMPUTE_PASS
    from softpvtol_gym.baselines.leaderboard.jobs import stale_parts

    job = _learned_job(selection_episodes=2, selection_seed=2_000_000)
    scored = [ep(0.1) | {"compute_us_single": 15.0}] * 2
    unmeasured = [ep(0.1)] * 2
    record = {"job": dataclasses.asdict(job), "inference": "lean", "compute_pass": COMPUTE_PASS,
              "eval": {"nominal": scored, "model_gap": scored},
              "selection": {"hover": {"nominal": [ep(0.3)] * 2, "model_gap": [ep(0.3)] * 2}}}
    assert stale_parts(job, record) == {}
    assert stale_parts(job, record | {"selection": {"hover": {"nominal": [ep(0.3)] * 2}}}) == {
        ("hover", "model_gap"): ("selection",)}
    assert stale_parts(job, record | {"eval": {"nominal": scored, "model_gap": unmeasured}}) == {
        ("hover", "model_gap"): ("compute",)}
    # scored with another forward pass (or before the lean path, which recorded none): every part again
    every = {("hover", t): ("test", "selection", "compute") for t in ("nominal", "model_gap")}
    assert stale_parts(job, {k: v for k, v in record.items() if k != "inference"}) == every
    assert stale_parts(job, record | {"inference": "torch"}) == every
    assert stale_parts(dataclasses.replace(job, inference="torch"), record | {"inference": "torch"}) == {}
    # an analytic job has no forward pass to check; a job without selection episodes ignores them
    analytic = dataclasses.replace(job, policy="passivity-bounded", train_tier=None, selection_episodes=0)
    # identical test episodes (a deterministic task and tier): an analytic job's round-off probe is due
    assert stale_parts(analytic, {"job": {"task": "hover"}, "compute_pass": COMPUTE_PASS,
                                  "eval": {"nominal": scored, "model_gap": scored}}) == {
        ("hover", t): ("roundoff",) for t in ("nominal", "model_gap")}
    probes = [ep(0.1 + 1e-9 * i) for i in range(4)]
    analytic_record = {"job": {"task": "hover"}, "compute_pass": COMPUTE_PASS,
                       "eval": {"nominal": scored, "model_gap": scored},
                       "roundoff": {"hover": {"nominal": probes, "model_gap": probes}}}
    assert stale_parts(analytic, analytic_record) == {}
    # an episode recorded before a metric was added: re-run to add it (the recorded ones must reproduce)
    old = [{k: v for k, v in e.items() if k != "fraction_within_1cm"} for e in scored]
    assert stale_parts(analytic, analytic_record | {"eval": {"nominal": old, "model_gap": scored}}) == {
        ("hover", "nominal"): ("metrics",)}
    # a per-robot compute measured another way (or before the way was recorded): only that pass again
    compute_only = {("hover", t): ("compute",) for t in ("nominal", "model_gap")}
    assert stale_parts(analytic, analytic_record | {"compute_pass": "evenly spaced observations"}) == compute_only
    assert stale_parts(analytic, {k: v for k, v in analytic_record.items() if k != "compute_pass"}) == compute_only


def test_rescoring_runs_only_the_missing_parts_and_measures_the_per_robot_compute(tmp_path):
    """A passivity job on 2 test and 2 selection hover episodes: then, with its selection episodes removed, only
    those are run again (the test episodes are kept as they are), and the per-robot compute is in every test
    episode."""
    job = Job(policy="passivity-bounded", action_mode="actuators", task="hover", train_tier=None, seed=0,
              eval_tiers=("nominal",), eval_episodes=2, eval_seed=1_000_000, allocation="exact", loop="bounded",
              selection_episodes=2, selection_seed=2_000_000)
    record = run_job(job, tmp_path)
    test, chosen = record["eval"]["nominal"], record["selection"]["hover"]["nominal"]
    assert len(test) == len(chosen) == 2 and record["inference"] is None
    from softpvtol_gym.baselines.evaluation import COMPUTE_PASS

    assert record["compute_pass"] == COMPUTE_PASS
    assert {e["compute_us_single"] for e in test} == {test[0]["compute_us_single"]} and test[0]["compute_us_single"] > 0
    assert [e["return"] for e in chosen] != [e["return"] for e in test]  # other seeds, other episodes
    path = job.folder(tmp_path) / "eval.json"
    stored = json.loads(path.read_text())
    stored["eval"]["nominal"][0]["return"] = 12345.0  # a marker: kept unless the test episodes run again
    del stored["selection"]
    path.write_text(json.dumps(stored))
    again = run_job(job, tmp_path)
    assert again["eval"]["nominal"][0]["return"] == 12345.0
    from softpvtol_gym.baselines.evaluation import without_timing

    assert [without_timing(e) for e in again["selection"]["hover"]["nominal"]] == [without_timing(e) for e in chosen]


def test_the_headline_chooses_on_selection_episodes_and_reports_the_test_episodes():
    meta = {"tasks": ["hover"], "tiers": ["wind"]}
    rows = [_window_row("passivity-bounded", "passivity-bounded", 0.6, [0.5, 0.7]),
            _window_row("passivity-integral", "passivity-integral", 0.5, [0.45, 0.55]),
            _window_row("PPO-a", "ppo", 0.02, [0.015, 0.03], whole=0.2)]
    for r, chosen in zip(rows, (0.1, 0.9, 0.02)):  # on the selection episodes the bounded loop looked best
        r["selection"] = {"episodes": 10, "crash_rate": 0.0, f"{WHOLE}_iqm": r[f"{WHOLE}_iqm"],
                          f"{STEADY}_iqm": chosen}
    (steady,) = [r for r in window_headline({"meta": meta, "aggregates": rows}) if r["window"] == "steady"]
    assert steady["model_based"]["entry"] == "passivity-bounded" and steady["selected_on"] == "selection"
    assert steady["model_based"][f"{STEADY}_iqm"] == 0.6  # reported on the test episodes
    del rows[1]["selection"]  # a row without selection episodes: every side is chosen on the test episodes
    (steady,) = [r for r in window_headline({"meta": meta, "aggregates": rows}) if r["window"] == "steady"]
    assert steady["model_based"]["entry"] == "passivity-integral" and steady["selected_on"] == "test"


def test_aggregate_rows_hold_the_per_robot_compute_the_selection_iqms_and_the_ci_size():
    cells = [cell("PPO", s, [ep(0.1 * (s + 1)) | {"compute_us_single": 10.0 + s}, ep(0.2)]) for s in range(3)]
    for c in cells:
        c["selection"] = [ep(0.5), ep(0.7)]
    (row,) = aggregate(cells)
    assert row["compute_us_single"] == 11.0  # the median over runs
    assert row["ci_values"] == 6 and row["selection"]["episodes"] == 2
    assert row["selection"][f"{STEADY}_iqm"] == pytest.approx(stats.trim_mean([0.5, 0.7] * 3, 0.25))


def test_a_ci_from_fewer_than_ten_values_is_marked_with_a_dagger():
    from softpvtol_gym.baselines.leaderboard.render import FEW_VALUES, FEW_VALUES_NOTE, fmt_window

    (few,) = aggregate([cell("PPO", 0, [ep(0.1), ep(0.2), ep(0.3)])])
    (enough,) = aggregate([cell("PPO", s, [ep(0.1), ep(0.2), ep(0.3)]) for s in range(4)])
    assert (few["ci_values"], enough["ci_values"]) == (3, 12)
    assert FEW_VALUES in fmt_window(few, STEADY) and FEW_VALUES not in fmt_window(enough, STEADY)
    page = render_markdown({"meta": {"command": "x", "commit": "x", "date": "x", "tasks": ["track_paper"],
                                     "tiers": ["nominal"], "episodes": 3, "eval_seed": 1_000_000, "seeds": 1,
                                     "bootstrap_reps": 2000, "poi_bootstrap_reps": 300},
                            "aggregates": [few | {"entry": "PPO-a"}, enough | {"entry": "PPO-b"}], "cells": []})
    line_few = next(line for line in page.splitlines() if "| PPO-a |" in line)
    line_enough = next(line for line in page.splitlines() if "| PPO-b |" in line)
    assert FEW_VALUES in line_few and FEW_VALUES not in line_enough and FEW_VALUES_NOTE in page


@pytest.mark.parametrize("evaluation, message", [
    ("{episodes: 20, seed: 1000000, tiers: [nominal], selection_episodes: 10, selection_seed: 1000010}",
     r"the selection episodes \(seeds 1,000,010 to 1,000,019\) overlap the test episodes"),
    ("{episodes: 20, seed: 1000000, tiers: [nominal], selection_episodes: -1}",
     r"evaluation\.selection_episodes must be an integer in \[0, 10,000\], got -1"),
    ("{episodes: 20, seed: 1000000, tiers: [nominal], selection_seed: 10}",
     r"evaluation\.selection_seed must be an integer >= 1,000,000"),
    ("{episodes: 20, seed: 1000000, tiers: [nominal], inference: onnx}",
     r"evaluation\.inference must be one of \['lean', 'torch'\], got 'onnx'"),
])
def test_bad_selection_and_inference_settings_are_refused(tmp_path, evaluation, message):
    path = tmp_path / "spec.yml"
    path.write_text(f"evaluation: {evaluation}\ntasks: [hover]\ntrained: []\nseeds: [0]\n")
    with pytest.raises(ConfigError, match=message):
        load_jobs(path)


def test_a_deterministic_analytic_job_gets_its_roundoff_probe_and_new_metrics_replay(tmp_path):
    """track_paper nominal (one reference, one start): the job's two test episodes are one outcome, so its result
    holds the round-off probe; an episode recorded without ``fraction_within_1cm`` gets it from a replay that must
    reproduce every recorded metric."""
    from softpvtol_gym.baselines.leaderboard.episodes import ROUNDOFF_STARTS
    from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, stale_parts

    job = Job(policy="passivity-bounded", action_mode="actuators", task="track_paper", train_tier=None, seed=0,
              eval_tiers=("nominal",), eval_episodes=2, eval_seed=1_000_000, allocation="exact", loop="bounded")
    record = run_job(job, tmp_path)
    test, probes = record["eval"]["nominal"], record["roundoff"]["track_paper"]["nominal"]
    assert len(probes) == len(ROUNDOFF_STARTS) and not any(p["crashed"] for p in probes)
    moved = [abs(p["rms_position_error"] - test[0]["rms_position_error"]) for p in probes]
    assert 0 < max(moved) < 1e-6  # the start moved by 1e-9 m: the episode moves, a little
    path = job.folder(tmp_path) / EVAL_FILE
    stored = json.loads(path.read_text())
    for e in stored["eval"]["nominal"]:
        del e["fraction_within_1cm"]
    path.write_text(json.dumps(stored))
    assert stale_parts(job, stored) == {("track_paper", "nominal"): ("metrics",)}
    again = run_job(job, tmp_path)
    assert again["eval"]["nominal"] == test  # the metric added, the wall-time figures kept
    for e in stored["eval"]["nominal"]:
        e["return"] += 1.0  # a recorded metric the code no longer reproduces
    path.write_text(json.dumps(stored))
    with pytest.raises(ConfigError, match="no longer reproduces"):
        run_job(job, tmp_path)
