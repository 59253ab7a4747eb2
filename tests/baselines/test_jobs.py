"""A learned cell is scored on tasks it never trained on (``also_evaluated_on`` in the leaderboard
spec): the spec is checked, a finished job only evaluates what a new task adds, and the leaderboard
labels the cross-task rows with the training task."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, missing_evaluations, pending, run_jobs

HEAD = "evaluation: {episodes: 2, seed: 1000000, tiers: [nominal, wind]}\npassivity: []\n"
CELL = "{action_mode: actuators, task: track_random, tier: nominal, timesteps: 64%s}"


def write_spec(path, also: str = "", tasks: str = "[hover, track_random]"):
    path.write_text(HEAD + f"tasks: {tasks}\ntrained: [{CELL % also}]\nseeds: [0]\n")
    return path


@pytest.mark.parametrize("also, message", [
    (", also_evaluated_on: [track_random]", "must list other tasks than the cell's own"),
    (", also_evaluated_on: [hover, hover]", "must list other tasks than the cell's own ('track_random'), each once"),
    (", also_evaluated_on: [track_paper]", "also_evaluated_on (a task of the spec's tasks) must be one of"),
    (", also_evaluated_on: hover", "also_evaluated_on must be a list"),
])
def test_bad_also_evaluated_on_is_refused(tmp_path, also, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        load_jobs(write_spec(tmp_path / "spec.yml", also))


def test_cell_without_other_tasks_is_evaluated_on_its_own_task_only(tmp_path):
    (job,) = load_jobs(write_spec(tmp_path / "spec.yml"))
    assert job.eval_tasks == ("track_random",) and job.other_eval_tasks == ()
    (job,) = load_jobs(write_spec(tmp_path / "spec.yml", ", also_evaluated_on: [hover]"))
    assert job.eval_tasks == ("track_random", "hover")
    assert job.name == "ppo_actuators_track_random_nominal/seed_0"  # the folder does not depend on it


@pytest.mark.slow  # one 4,096-step PPO training
def test_added_task_evaluates_only_what_is_missing_and_reaches_the_leaderboard(tmp_path):
    from softpvtol_gym.baselines.leaderboard.stats import aggregate, collect

    root = tmp_path / "runs"
    spec = write_spec(tmp_path / "spec.yml", ', hp: ["learning_rate=1e-3"]')
    (job,) = load_jobs(spec)
    with ThreadPoolExecutor(max_workers=1) as ex:
        run_jobs([job], ex, root, progress=False)
    first = json.loads((job.folder(root) / EVAL_FILE).read_text())
    from softpvtol_gym.baselines.config.run_config import RunConfig

    saved = RunConfig.load(job.folder(root) / "config.yaml")  # the cell's override is what trained
    assert saved.hyperparams["learning_rate"] == 1e-3 and saved.overrides == ["learning_rate=1e-3"]
    assert "eval_other_tasks" not in first and set(first["eval"]) == {"nominal", "wind"}

    spec = write_spec(tmp_path / "spec.yml", ", also_evaluated_on: [hover]")
    (job,) = load_jobs(spec)
    assert missing_evaluations(job, first) == [("hover", "nominal"), ("hover", "wind")]
    assert pending([job], root) == [job]
    with ThreadPoolExecutor(max_workers=1) as ex:
        run_jobs(pending([job], root), ex, root, progress=False)
    second = json.loads((job.folder(root) / EVAL_FILE).read_text())
    assert second["eval"] == first["eval"]  # kept, not re-run
    assert set(second["eval_other_tasks"]) == {"hover"} and set(second["eval_other_tasks"]["hover"]) == {"nominal",
                                                                                                        "wind"}
    assert len(second["eval_other_tasks"]["hover"]["wind"]) == 2 and pending([job], root) == []
    # the other task really ran: the same episodes as evaluating the committed model on hover directly
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    policy, config = LearnedPolicy.load(job.folder(root))
    from softpvtol_gym.baselines.evaluation import without_timing

    assert run_episodes(policy, "actuators", "hover", "wind", 2, 1000000, env_kwargs=config.eval_env_kwargs()) == [
        without_timing(e) for e in second["eval_other_tasks"]["hover"]["wind"]]

    cells, missing = collect(root, spec)
    assert missing == []
    labels = {(c["task"], c["entry"]) for c in cells}
    assert labels == {("track_random", "PPO-actuators (trained on nominal)"),
                      ("hover", "PPO-actuators (trained on track_random, nominal)")}
    rows = aggregate(cells)
    assert {(r["task"], r["tier"], r["train_task"]) for r in rows} == {
        (t, tier, "track_random") for t in ("hover", "track_random") for tier in ("nominal", "wind")}

    # a result that lacks a task the spec now lists is reported missing, not silently dropped
    spec = write_spec(tmp_path / "spec2.yml", ", also_evaluated_on: [hover, track_paper]",
                      tasks="[hover, track_paper, track_random]")
    _, missing = collect(root, spec)
    assert missing == ["ppo_actuators_track_random_nominal/seed_0 on track_paper/nominal, track_paper/wind"]


@pytest.mark.parametrize("hp, message", [
    ('"learning_rate=1e-3"', "hp must be a list"),
    ("[3]", "hp must be a list of 'key=value' strings"),
    ('["learning_rate"]', "must look like key=value"),
    ('["learning_rate=-1"]', "learning_rate"),
    ('["bogus_key=1"]', "bogus_key"),
])
def test_bad_cell_hyperparameter_overrides_are_refused(tmp_path, hp, message):
    with pytest.raises(ConfigError, match=r"trained\[0\]\.hp") as info:
        load_jobs(write_spec(tmp_path / "spec.yml", f", hp: {hp}"))
    assert message in str(info.value)


def test_cell_hyperparameter_overrides_reach_the_job(tmp_path):
    (job,) = load_jobs(write_spec(tmp_path / "spec.yml", ', hp: ["learning_rate=1e-3", "gamma=0.995"]'))
    assert job.hp == ("learning_rate=1e-3", "gamma=0.995")


def test_worker_environment_is_the_workers_only_and_numba_keeps_its_cache_directory():
    """``ProcessPerJobExecutor(worker_env=...)`` sets the variables in each worker, not in the driver: a lasting
    NUMBA_* change in the driver made numba reload its configuration at the next compile, dropping the cache
    directory the package had set (everything compiled again, into the source tree)."""
    import os

    import numba
    from numba.core import config

    import softpvtol_gym
    from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor
    from tests.baselines._stub_jobs import environment_variable

    name = "NUMBA_NUM_THREADS"
    before = os.environ.get(name)
    with ProcessPerJobExecutor(max_workers=1, worker_env={name: "1"}) as ex:
        assert ex.submit(environment_variable, name).result(timeout=120) == "1"
    assert os.environ.get(name) == before

    @numba.njit(cache=False)
    def _compiled_after_the_jobs(x):
        return x + 1

    assert _compiled_after_the_jobs(1) == 2  # a compile reloads numba's configuration if the environment changed
    assert config.CACHE_DIR == str(softpvtol_gym.NUMBA_CACHE_DIR)
