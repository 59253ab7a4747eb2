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
    ("{teacher: integral, task: hover, tier: nominal, options: {also_tiers: noisy}}",
     "options.also_tiers must be a list of tiers flown besides 'nominal', got 'noisy'"),
    ("{teacher: integral, task: hover, tier: nominal, options: {also_tiers: [nominal]}}",
     "tiers must be distinct names"),
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


#: one PPO update of 2 x 32 steps
FINE_TUNE = ("{action_mode: actuators, task: hover, tier: nominal, timesteps: 64, recipe: student-finetune, "
             "hp: [n_envs=2, n_steps=32, batch_size=64], init_from: distilled-integral_hover_nominal%s}")


def write_fine_tuning_spec(path, extra: str = ""):
    path.write_text(HEAD.replace("trained: []", f"trained: [{FINE_TUNE % extra}]") + f"distilled: [{TINY}]\n")
    return path


@pytest.mark.parametrize("extra, words", [
    ("", None),
    (", imitation: {teacher: integral, weight: 1.0, decay_steps: 32, epochs: 1}", None),
    (", imitation: {teacher: integral, weight: 1.0}", "lacks the keys ['decay_steps', 'epochs']"),
    (", imitation: {teacher: integral, weight: -1.0, decay_steps: 32, epochs: 1}", "imitation must be None or"),
])
def test_a_fine_tuning_cell_names_a_distilled_cell_and_its_imitation_term(tmp_path, extra, words):
    spec = write_fine_tuning_spec(tmp_path / "spec.yml", extra)
    if words is not None:
        with pytest.raises(ConfigError, match=r"trained\[0\]\.imitation") as info:
            load_spec(spec)
        assert words in str(info.value)
        return
    (job,) = [j for j in load_jobs(spec) if j.policy == "ppo"]
    assert job.init_from == "distilled-integral_hover_nominal"
    assert job.name == "ppo-student-finetune_hover_nominal/seed_0"
    assert dict(job.imitation) == ({} if not extra else {"teacher": "integral", "weight": 1.0, "decay_steps": 32,
                                                         "epochs": 1})


@pytest.mark.parametrize("cell, words", [
    (FINE_TUNE.replace("distilled-integral_hover_nominal", "distilled-mpc_hover_nominal") % "",
     "init_from (the folder of a distilled cell of the spec) must be one of ['distilled-integral_hover_nominal']"),
    ("{action_mode: actuators, task: hover, tier: nominal, timesteps: 64, "
     "imitation: {teacher: integral, weight: 1.0, decay_steps: 32, epochs: 1}}", "imitation needs init_from"),
    ("{action_mode: residual, task: hover, tier: nominal, timesteps: 64, init_from: distilled-integral_hover_nominal}",
     "has action_mode actuators, got 'residual'"),
])
def test_bad_fine_tuning_cells_are_refused(tmp_path, cell, words):
    spec = tmp_path / "spec.yml"
    spec.write_text(HEAD.replace("trained: []", f"trained: [{cell}]") + f"distilled: [{TINY}]\n")
    with pytest.raises(ConfigError, match=r"trained\[0\]") as info:
        load_spec(spec)
    assert words in str(info.value)


def test_a_fine_tuning_job_without_its_student_says_which_job_to_run_first(tmp_path):
    from softpvtol_gym.baselines.leaderboard.jobs import run_job

    (job,) = [j for j in load_jobs(write_fine_tuning_spec(tmp_path / "spec.yml")) if j.policy == "ppo"]
    with pytest.raises(ConfigError, match="run its distilled job first .*--only distilled-integral_hover_nominal"):
        run_job(job, tmp_path / "runs")


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
    spec = write_fine_tuning_spec(tmp_path / "spec.yml", ", imitation: {teacher: integral, weight: 1.0, "
                                                         "decay_steps: 32, epochs: 1}")
    jobs = load_jobs(spec)
    with ThreadPoolExecutor(max_workers=1) as ex:
        run_jobs(jobs, ex, root, progress=False)
    assert pending(jobs, root) == []
    (student,) = [j for j in jobs if j.policy == "distilled"]
    folder = student.folder(root)
    record = json.loads((folder / EVAL_FILE).read_text())
    distilled = json.loads((folder / "distill.json").read_text())
    assert record["job"]["teacher"] == "integral" and record["train_seconds"] == round(distilled["seconds"], 1)
    assert [r["kind"] for r in distilled["rounds"]] == ["behaviour cloning", "dagger"]
    assert not (root / (student.name + ".run")).exists()  # the datasets are not kept

    cells, missing = collect(root, spec)
    assert missing == []
    label = "distilled integral (trained on nominal)"
    assert {c["entry"] for c in cells} == {"passivity-integral", label, "PPO student-finetune (trained on nominal)"}
    rows = aggregate(cells)
    (row,) = [r for r in rows if r["entry"] == label]
    assert (row["policy"], row["teacher"], row["variant"]) == ("distilled", "integral", None)
    verdicts = window_headline({"meta": {"tasks": ["hover"], "tiers": ["nominal"]}, "aggregates": rows})
    assert verdicts and all(v["learned"]["policy"] in ("distilled", "ppo")
                            and v["model_based"]["entry"] == "passivity-integral" for v in verdicts)
    budgets = {b["name"]: b for b in training_budgets({"cells": cells})}
    assert budgets["distilled integral"]["train_seconds"] == [record["train_seconds"]]

    # the fine-tuning job started from this seed's student, with its network, statistics and env options
    from softpvtol_gym.baselines.config.run_config import RunConfig

    (tuned,) = [j for j in jobs if j.policy == "ppo"]
    config = RunConfig.load(tuned.folder(root) / "config.yaml")
    student_config = RunConfig.load(folder / "config.yaml")
    assert config.init_from == str(folder) and config.imitation["teacher"] == "integral"
    assert config.env_options == student_config.env_options == {"observe_error_integral": True,
                                                                 "error_integral_limit": 8.0,
                                                                 "error_integral_error_limit": 0.5}
    assert config.hyperparams["policy_kwargs"] == student_config.hyperparams["policy_kwargs"]
    assert config.train_env_options == {"precision_reward_weight": 1.0, "precision_reward_scale": 0.01}


def test_the_docs_rounds_table_is_generated_from_the_committed_students():
    from softpvtol_gym.baselines.commands.leaderboard import distilled_records
    from softpvtol_gym.baselines.leaderboard.distilled import ROUNDS_BLOCK, rounds_table
    from softpvtol_gym.baselines.util.blocks import read_block
    from tests.conftest import RESULTS, ROOT

    records = distilled_records(RESULTS / "leaderboard_runs")
    assert {name: len(seeds) for name, seeds in records.items()} == {
        "distilled integral": 5, "distilled integral small": 5, "distilled integral small-matched": 5,
        "distilled integral small-matched-history": 5, "distilled mpc small": 5, "distilled mpc robust": 5,
        "distilled mpc robust-bounded": 5, "distilled mpc robust-bounded-small": 5}
    assert read_block(*ROUNDS_BLOCK, ROOT / "docs" / "baselines.md") == rounds_table(records).strip()


def test_the_docs_ablation_is_generated_from_the_committed_leaderboard_students_and_reward_runs():
    from softpvtol_gym.baselines.commands.leaderboard import distilled_records, finetune_reward_runs
    from softpvtol_gym.baselines.leaderboard.distilled import ABLATION_BLOCK, ablation_table
    from softpvtol_gym.baselines.util.blocks import read_block
    from tests.conftest import RESULTS, ROOT

    aggregates = json.loads((RESULTS / "leaderboard.json").read_text())["aggregates"]
    reward_runs = finetune_reward_runs(RESULTS / "distill_runs" / "finetune_reward")
    assert set(reward_runs) == {"reward", "noreward"}
    table = ablation_table(aggregates, distilled_records(RESULTS / "leaderboard_runs"), reward_runs)
    assert read_block(*ABLATION_BLOCK, ROOT / "docs" / "baselines.md") == table.strip()
    for entry in ("distilled integral small (trained on nominal)", "PPO student-finetune (trained on nominal)",
                  "distilled mpc small (trained on nominal)", "PPO student-finetune (trained on hard)",
                  "distilled integral small-matched-history (trained on nominal)",
                  "PPO student-history-finetune (trained on hard)",
                  "PPO student-history-finetune (trained on model_gap)"):
        assert f"| {entry} |" in table  # the leaderboard holds the cells the ablation reads


def test_a_residual_students_cell_is_a_job_of_the_residual_mode_with_the_mixture_settings(tmp_path):
    spec = write_spec(tmp_path / "spec.yml", "{teacher: integral, task: hover, tier: nominal, variant: residual, "
                                             "options: {residual_on: integral, teacher_shares: [0.5, 0.0], "
                                             "rounds: 3, also_tasks: [track_random]}}")
    (job,) = [j for j in load_jobs(spec) if j.policy == "distilled"]
    assert job.action_mode == "residual"
    config = distill_config(job.teacher, job.task, job.train_tier, job.seed, job.distill_options)
    assert (config.residual_on, config.teacher_shares, config.also_tasks) == ("integral", (0.5, 0.0),
                                                                               ("track_random",))
    assert config.run_config().action_mode == "residual"


def test_a_privileged_mixture_cell_flies_its_tier_and_the_others_and_its_results_say_privileged(tmp_path):
    import dataclasses

    from softpvtol_gym.baselines.leaderboard.distilled import student_fields
    from softpvtol_gym.baselines.leaderboard.stats import entry_label

    spec = write_spec(tmp_path / "spec.yml", "{teacher: mpc, task: hover, tier: nominal, variant: robust, "
                                             "options: {privileged: true, also_tiers: [noisy, hard], "
                                             "also_tasks: [track_random]}}, " + TINY)
    robust, plain = [j for j in load_jobs(spec) if j.policy == "distilled"]
    config = distill_config(robust.teacher, robust.task, robust.train_tier, robust.seed, robust.distill_options)
    assert config.tiers == ("nominal", "noisy", "hard") and config.privileged
    assert config.tasks == ("hover", "track_random") and robust.name == "distilled-mpc-robust_hover_nominal/seed_0"
    # the job as its result records it (JSON): privileged, trained on a mixture; the plain student neither
    as_recorded = [json.loads(json.dumps(dataclasses.asdict(j))) for j in (robust, plain)]
    assert [student_fields(j) for j in as_recorded] == [
        {"privileged": True, "trained_on": "hover + track_random, 3 tiers"}, {}]
    assert entry_label(as_recorded[0]) == "distilled mpc robust (trained on hover + track_random, 3 tiers)"
    assert entry_label(as_recorded[1]) == "distilled integral (trained on nominal)"
