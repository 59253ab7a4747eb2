"""Distilled cells of the leaderboard (the spec's ``distilled`` list): the spec is checked, each seed is a job
that distils its student and is evaluated like every learned entry, and the leaderboard counts it as learned,
naming its teacher."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.distilled import distill_config
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, pending, run_jobs
from softpvtol_gym.baselines.leaderboard.spec import is_learned, load_spec

HEAD = ("evaluation: {episodes: 2, seed: 1000000, tiers: [nominal]}\n"
        "analytic: [{name: passivity-integral, kind: passivity, allocation: exact, loop: integral}]\n"
        "tasks: [hover]\ntrained: []\nseeds: [0]\n")
#: a student of 2 rounds of 1 hover episode each, fitted for one epoch: seconds
TINY = ("{teacher: integral, task: hover, tier: nominal, "
        "options: {rounds: 2, episodes: 1, epochs: 1, batch_size: 512, eval_episodes: 0, net_arch: [8, 8]}}")


def write_spec(path, cells: str):
    path.write_text(HEAD + f"distilled: [{cells}]\n")
    return path


@pytest.mark.parametrize("cell, words", [
    ("{teacher: integral, task: hover}", "lacks the keys ['tier']"),
    ("{teacher: oracle, task: hover, tier: nominal}", "teacher must be one of"),
    ("{teacher: integral, task: track_paper, tier: nominal}", "task (a task of the spec's tasks) must be one of"),
    ("{teacher: integral, task: hover, tier: breezy}", "tier must be one of"),
    ("{teacher: integral, task: hover, tier: nominal, options: {seed: 3}}", "options ['seed'] are not"),
    ("{teacher: integral, task: hover, tier: nominal, options: {epochs: 0}}", "epochs must be an integer"),
    ("{teacher: integral, task: hover, tier: nominal, options: [1]}", "options must be a mapping"),
    ("{teacher: integral, task: hover, tier: nominal, variant: 'a b'}", "variant"),
    ("{teacher: integral, task: hover, tier: nominal, also_evaluated_on: [hover]}", "other tasks than the cell's"),
    ("{teacher: integral, task: hover, tier: nominal, colour: red}", "unknown keys ['colour']"),
    ("{teacher: integral, task: hover, tier: nominal}, {teacher: integral, task: hover, tier: nominal}",
     "repeats the cell"),
])
def test_bad_distilled_cells_are_refused_naming_the_key(tmp_path, cell, words):
    with pytest.raises(ConfigError, match=r"distilled\[\d\]") as info:
        load_spec(write_spec(tmp_path / "spec.yml", cell))
    assert words in str(info.value)


def test_a_distilled_cell_is_one_learned_job_per_seed_with_its_teacher_and_settings(tmp_path):
    spec = write_spec(tmp_path / "spec.yml", "{teacher: integral, task: hover, tier: nominal, variant: small, "
                                             "options: {net_arch: [8, 8], epochs: 2}}")
    jobs = [j for j in load_jobs(spec) if j.policy == "distilled"]
    (job,) = jobs
    assert job.learned and is_learned("distilled") and not is_learned("passivity-integral")
    assert job.name == "distilled-integral-small_hover_nominal/seed_0" and job.action_mode == "actuators"
    config = distill_config(job.teacher, job.task, job.train_tier, job.seed, job.distill_options)
    assert (config.teacher, config.tiers, config.net_arch, config.epochs, config.seed) == (
        "integral", ("nominal",), (8, 8), 2, 0)


def test_an_analytic_entry_may_not_take_a_learned_policys_name(tmp_path):
    spec = tmp_path / "spec.yml"
    spec.write_text(HEAD.replace("name: passivity-integral", "name: distilled"))
    with pytest.raises(ConfigError, match="is taken"):
        load_spec(spec)


@pytest.mark.slow  # a tiny distillation and 2 evaluation episodes per entry
def test_a_distilled_job_distils_evaluates_and_reaches_the_leaderboard_as_learned(tmp_path):
    from softpvtol_gym.baselines.leaderboard.headline import window_headline
    from softpvtol_gym.baselines.leaderboard.render import training_budgets
    from softpvtol_gym.baselines.leaderboard.stats import aggregate, collect

    root = tmp_path / "runs"
    spec = write_spec(tmp_path / "spec.yml", TINY)
    jobs = load_jobs(spec)
    with ThreadPoolExecutor(max_workers=1) as ex:
        run_jobs(jobs, ex, root, progress=False)
    assert pending(jobs, root) == []
    (student,) = [j for j in jobs if j.learned]
    folder = student.folder(root)
    record = json.loads((folder / EVAL_FILE).read_text())
    distilled = json.loads((folder / "distill.json").read_text())
    assert record["job"]["teacher"] == "integral" and record["train_seconds"] == round(distilled["seconds"], 1)
    assert [r["kind"] for r in distilled["rounds"]] == ["behaviour cloning", "dagger"]
    assert not (root / (student.name + ".run")).exists()  # the datasets are not kept

    cells, missing = collect(root, spec)
    assert missing == []
    label = "distilled integral (trained on nominal)"
    assert {c["entry"] for c in cells} == {"passivity-integral", label}
    rows = aggregate(cells)
    (row,) = [r for r in rows if r["entry"] == label]
    assert (row["policy"], row["teacher"], row["variant"]) == ("distilled", "integral", None)
    verdicts = window_headline({"meta": {"tasks": ["hover"], "tiers": ["nominal"]}, "aggregates": rows})
    assert verdicts and all(v["learned"]["entry"] == label and v["model_based"]["entry"] == "passivity-integral"
                            for v in verdicts)
    (budget,) = training_budgets({"cells": cells})
    assert budget["name"] == "distilled integral" and budget["train_seconds"] == [record["train_seconds"]]


def test_the_docs_rounds_table_is_generated_from_the_committed_students():
    from softpvtol_gym.baselines.commands.leaderboard import distilled_records
    from softpvtol_gym.baselines.leaderboard.distilled import ROUNDS_BLOCK, rounds_table
    from softpvtol_gym.baselines.util.blocks import read_block
    from tests.conftest import RESULTS, ROOT

    records = distilled_records(RESULTS / "leaderboard_runs")
    assert {name: len(seeds) for name, seeds in records.items()} == {"distilled integral": 5,
                                                                      "distilled integral small": 5}
    assert read_block(*ROUNDS_BLOCK, ROOT / "docs" / "baselines.md") == rounds_table(records).strip()
