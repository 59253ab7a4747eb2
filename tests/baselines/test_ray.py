"""The job list on Ray (``run_jobs.py --executor ray``) gives the process pool's results,
skips finished jobs, reports a failing job in one line; the shared-root check; the Tune search writes a valid
best configuration with its provenance. Ray runs locally with 2 CPUs (no dashboard, a fresh short temp dir)."""

from __future__ import annotations

import json
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from softpvtol_gym.baselines.commands.run_jobs import main as run_jobs_main
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import without_timing
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, ROOT_TOKEN_FILE, check_shared_root, load_jobs, run_jobs

# one worker runs every test that starts Ray (pyproject: --dist loadgroup), so no two local Rays meet
pytestmark = pytest.mark.xdist_group("ray")

# one analytic job and one learned job (a single PPO rollout), two evaluation tiers of 2 episodes
SPEC = ("evaluation: {episodes: 2, seed: 1000000, tiers: [nominal, wind]}\n"
        "passivity: [{name: passivity-exact, allocation: exact}]\n"
        "tasks: [hover]\n"
        "trained: [{action_mode: residual, task: hover, tier: nominal, timesteps: 1}]\n"
        "seeds: [0]\n")
#: files of a learned job that must be byte-identical whichever executor ran it. Not byte-identical even between two
#: pool runs: model.json (it holds the observation space's RNG state, which SB3 leaves unseeded) and the header
#: of model.safetensors (its metadata's key order); the tensors of model.safetensors are compared instead.
SAME_BYTES = ("vecnormalize.json", "config.yaml")
#: evaluations.json: the same apart from its clock readings (train_seconds, wall_time)
CLOCK_KEYS = ("train_seconds", "wall_time")


def _tensors(path: Path) -> dict:
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        return {"metadata": f.metadata(), **{k: f.get_tensor(k) for k in f.keys()}}


def _spec(tmp_path: Path) -> Path:
    path = tmp_path / "spec.yml"
    path.write_text(SPEC)
    return path


def _result(root: Path, job) -> dict:
    """What must not depend on the executor: the job and its per-episode evaluation."""
    rec = json.loads((job.folder(root) / EVAL_FILE).read_text())
    return {"job": rec["job"], "eval": {tier: [without_timing(e) for e in eps] for tier, eps in rec["eval"].items()}}


@pytest.mark.slow  # trains and evaluates with the pool and three times on Ray: ~20 s on an idle 2-core machine
def test_ray_gives_the_pools_results_and_skips_finished_jobs(tmp_path, capsys):
    spec = _spec(tmp_path)
    jobs = load_jobs(spec)
    pool_root, ray_root = tmp_path / "pool", tmp_path / "ray"
    common = ["--spec", str(spec), "--workers", "2", "--no-progress-bar"]
    assert run_jobs_main([*common, "--root", str(pool_root)]) == 0
    assert run_jobs_main([*common, "--executor", "ray", "--root", str(ray_root)]) == 0
    out = capsys.readouterr().out
    assert "Ray: 2 jobs on 2 CPUs" in out, out
    for job in jobs:
        assert _result(ray_root, job) == _result(pool_root, job), job.name
        assert len(_result(ray_root, job)["eval"]["wind"]) == 2
    learned = next(j for j in jobs if j.learned)
    for name in SAME_BYTES:
        assert (learned.folder(ray_root) / name).read_bytes() == (learned.folder(pool_root) / name).read_bytes(), name
    evals = [[{k: v for k, v in e.items() if k not in CLOCK_KEYS}
              for e in json.loads((learned.folder(r) / "evaluations.json").read_text())] for r in (ray_root, pool_root)]
    assert evals[0] == evals[1] and len(evals[0]) >= 2
    ray_model, pool_model = (_tensors(learned.folder(r) / "model.safetensors") for r in (ray_root, pool_root))
    assert ray_model.keys() == pool_model.keys() and len(ray_model) > 10
    for key, value in ray_model.items():
        assert np.array_equal(value, pool_model[key]) if key != "metadata" else value == pool_model[key], key
    assert not (ray_root / ROOT_TOKEN_FILE).exists()

    # resumable: only the job whose eval.json is gone runs again; the learned job is not touched
    analytic = next(j for j in jobs if not j.learned)
    (analytic.folder(ray_root) / EVAL_FILE).unlink()
    before = {p.name: p.read_bytes() for p in learned.folder(ray_root).iterdir()}
    assert run_jobs_main([*common, "--executor", "ray", "--root", str(ray_root)]) == 0
    out = capsys.readouterr().out
    assert f"[1/1] {analytic.name}" in out and learned.name not in out, out
    assert _result(ray_root, analytic) == _result(pool_root, analytic)
    assert {p.name: p.read_bytes() for p in learned.folder(ray_root).iterdir()} == before
    assert run_jobs_main([*common, "--executor", "ray", "--root", str(ray_root)]) == 0  # nothing left: no Ray
    assert "0 pending jobs" in capsys.readouterr().out


def test_a_job_failing_on_ray_is_one_line_and_the_others_finish(tmp_path, capsys):
    """The exception a Ray task raises reaches run_jobs as itself (not Ray's wrapper with a remote traceback)."""
    spec = _spec(tmp_path)
    root = tmp_path / "root"
    learned = next(j for j in load_jobs(spec) if j.learned)
    learned.folder(root).mkdir(parents=True)
    (learned.folder(root) / "model.zip").write_bytes(b"PK")  # a model of the earlier pickle-based format
    with pytest.raises(SystemExit) as exc:
        run_jobs_main(["--spec", str(spec), "--root", str(root), "--executor", "ray", "--workers", "2",
                       "--no-progress-bar"])
    out, err = capsys.readouterr()
    assert exc.value.code == 2
    failed = [line for line in err.splitlines() if line.startswith("[failed]")]
    assert len(failed) == 1 and learned.name in failed[0] and "earlier pickle-based format" in failed[0], err
    assert "Traceback" not in err and "RayTaskError" not in err, err
    assert "[1/2] passivity-exact_hover" in out, out
    assert err.strip().splitlines()[-1].startswith("run_jobs.py: error: 1 of 2 jobs failed"), err


def test_a_job_that_does_not_see_the_drivers_root_fails(tmp_path):
    (tmp_path / ROOT_TOKEN_FILE).write_text("another run")
    with pytest.raises(ConfigError, match="is another run's.*mounts at the same path"):
        check_shared_root(tmp_path, "abc")
    with pytest.raises(ConfigError, match="is missing"):
        check_shared_root(tmp_path / "elsewhere", "abc")
    check_shared_root(tmp_path, "another run")  # the driver's token: fine


def test_check_root_works_with_any_executor_and_leaves_no_token(tmp_path):
    spec = tmp_path / "spec.yml"
    spec.write_text(SPEC.replace("trained: [{action_mode: residual, task: hover, tier: nominal, timesteps: 1}]",
                                 "trained: []").replace("tiers: [nominal, wind]", "tiers: [nominal]"))
    jobs = load_jobs(spec)
    root = tmp_path / "root"
    root.mkdir()
    with ThreadPoolExecutor(max_workers=1) as ex:
        assert run_jobs(jobs, ex, root, check_root=True, progress=False) == [jobs[0].name]
    assert not (root / ROOT_TOKEN_FILE).exists()


@pytest.mark.parametrize("argv, message", [
    (["--address", "auto"], "--address needs --executor ray"),
    (["--executor", "ray", "--address", "auto", "--workers", "2"], "--workers with --address"),
    (["--executor", "ray", "--address", " "], "--address must be 'auto' or HOST:PORT"),
    (["--executor", "dask"], "invalid choice"),
])
def test_bad_executor_options_exit_2(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        run_jobs_main([*argv, "--spec", str(_spec(tmp_path)), "--root", str(tmp_path / "root")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "root").exists()


def test_an_unreachable_cluster_is_one_line(tmp_path, capsys, monkeypatch):
    import ray

    def no_cluster(**kwargs):
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(ray, "init", no_cluster)
    with pytest.raises(SystemExit) as exc:
        run_jobs_main(["--executor", "ray", "--address", "auto", "--spec", str(_spec(tmp_path)), "--root",
                       str(tmp_path / "root")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "cannot connect to a Ray cluster at 'auto'" in err and "ray start --head" in err
    assert len(err.strip().splitlines()) == 1, err


# ----------------------------------------------------------------------------------------- tune.py
TINY_SPACE = "ppo:\n  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n  n_epochs: {randint: [1, 2]}\n"
#: small rollouts, so that a trial is two PPO updates of 128 steps
TINY = ["--hp", "n_envs=4", "--hp", "n_steps=32", "--hp", "batch_size=64", "--timesteps", "256", "--reports", "2",
        "--eval-episodes", "2"]


@pytest.mark.slow  # 2 trials of 2 x 128 PPO steps on a 2-CPU local Ray: ~25 s on a busy 2-core machine
def test_a_tiny_search_writes_a_valid_best_configuration(tmp_path, capsys):
    import subprocess

    import yaml

    from softpvtol_gym.baselines.commands.tune import FORMAT, main
    from softpvtol_gym.baselines.config.hyperparams import apply_overrides, load_hyperparams
    from softpvtol_gym.baselines.config.run_config import RunConfig

    space, out = tmp_path / "space.yml", tmp_path / "best" / "best.yml"
    space.write_text(TINY_SPACE)
    assert main(["--trials", "2", "--workers", "2", "--space", str(space), "--out", str(out), *TINY]) == 0
    printed = capsys.readouterr().out
    assert "[2/2] trial" in printed and f"written to {out}" in printed, printed
    text = out.read_text()
    record = yaml.safe_load(text)
    assert "!!python" not in text and record["format"] == FORMAT
    assert record["cell"] == {"algo": "ppo", "env_id": "SoftPVTOL-v0", "action_mode": "residual", "task": "hover",
                              "tier": "nominal"}
    best = record["best"]
    assert set(best["searched"]) == {"learning_rate", "n_epochs"}
    assert 1e-4 <= best["searched"]["learning_rate"] <= 1e-3 and best["searched"]["n_epochs"] in (1, 2)
    base = apply_overrides(load_hyperparams("ppo", "residual"), ["n_envs=4", "n_steps=32", "batch_size=64"])
    # the written entry is the YAML entry + overrides + the searched values, and train.py --hp gives it back
    assert best["hyperparameters"] == {**base, **best["searched"]}
    assert apply_overrides(base, best["train_py_hp"]) == best["hyperparameters"]
    RunConfig(hyperparams=best["hyperparameters"], n_envs=4)  # a valid configuration
    assert record["objective"]["metric"] == "mean_return" and record["objective"]["eval_seed"] == 3_000_000
    trials = record["trials"]
    assert len(trials) == 2 and all(t["error"] is None for t in trials)
    finished = [t for t in trials if t["reports"] == 2]
    assert finished and best["objective"] == max(t["mean_return"] for t in finished)
    assert best["timesteps"] == 256 and math.isfinite(best["objective"])
    assert record["budget"]["trials"] == 2 and record["budget"]["timesteps_per_trial"] == 256
    assert record["budget"]["reports_per_trial"] == 2 and record["budget"]["trials_run_to_the_end"] == len(finished)
    assert record["search"]["scheduler"]["ASHAScheduler"]["max_t"] == 2 and record["seed"] == 0
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parents[2], capture_output=True, text=True)
    assert record["git"]["commit"] == (head.stdout.strip() or None)
    assert record["versions"]["ray"] and record["versions"]["optuna"] and record["date"].endswith("+00:00")


def _space(tmp_path: Path, text: str) -> str:
    path = tmp_path / "space.yml"
    path.write_text(text)
    return str(path)


BAD_TUNE_INPUT = [
    ("ppo:\n  n_epoch: {randint: [1, 2]}\n", [], "not a searchable PPO hyperparameter"),
    ("ppo:\n  policy_kwargs: {choice: [a]}\n", [], "not a searchable PPO hyperparameter"),
    ("ppo:\n  learning_rate: {loguniform: [0, 1.0e-3]}\n", [], "loguniform needs [low, high]"),
    ("ppo:\n  learning_rate: {uniform: [1.0e-3, 1.0e-4]}\n", [], "with low < high"),
    ("ppo:\n  n_epochs: {randint: [1.5, 3]}\n", [], "randint needs [low, high] with low < high, integers"),
    ("ppo:\n  batch_size: {choice: [1, 64]}\n", [], "ppo.batch_size: 1 is not a valid value"),
    ("ppo:\n  gamma: {choice: []}\n", [], "choice must be a non-empty list"),
    ("ppo:\n  gamma: {normal: [0.9, 1]}\n", [], "must be one of"),
    ("sac:\n  tau: {choice: [0.01]}\n", [], "have an entry 'ppo'"),
    (TINY_SPACE, ["--hp", "n_epochs=0"], "n_epochs must be an integer >= 1"),
    (TINY_SPACE, ["--workers", "0"], "must be >= 1"),
    (TINY_SPACE, ["--address", "auto", "--workers", "2"], "--workers with --address"),
    (TINY_SPACE, ["--trials", "0"], "must be >= 1"),
    (TINY_SPACE, ["--eval-seed", "5"], "must be >= 3,000,000"),
    (TINY_SPACE, ["--eval-seed", "1000000"], "must be >= 3,000,000"),
]


@pytest.mark.parametrize("space, extra, message", BAD_TUNE_INPUT, ids=[m for _, _, m in BAD_TUNE_INPUT])
def test_bad_tune_input_exits_2_before_ray_starts(space, extra, message, tmp_path, capsys, monkeypatch):
    import ray

    from softpvtol_gym.baselines.commands.tune import main

    monkeypatch.setattr(ray, "init", lambda **kw: pytest.fail("Ray was started"))
    with pytest.raises(SystemExit) as exc:
        main(["--space", _space(tmp_path, space), "--out", str(tmp_path / "best.yml"), *extra])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["space.yml"]


def test_tune_does_not_overwrite_its_output(tmp_path, capsys):
    from softpvtol_gym.baselines.commands.tune import main

    out = tmp_path / "best.yml"
    out.write_text("kept\n")
    with pytest.raises(SystemExit) as exc:
        main(["--space", _space(tmp_path, TINY_SPACE), "--out", str(out)])
    assert exc.value.code == 2 and "pass --force" in capsys.readouterr().err
    assert out.read_text() == "kept\n"


def test_the_default_search_space_is_valid_for_every_algorithm_and_mode():
    from softpvtol_gym.baselines.commands.tune import SPACE_FILE, load_space, stage_steps, tune_domains
    from softpvtol_gym.baselines.config.hyperparams import load_hyperparams

    for algo in ("ppo", "sac"):
        for mode in ("residual", "virtual", "actuators"):
            space = load_space(SPACE_FILE, algo, load_hyperparams(algo, mode))
            assert set(tune_domains(space)) == set(space) and len(space) >= 4
    assert stage_steps(1000, 4) == [250, 500, 750, 1000] and stage_steps(3, 4) == [1, 1, 2, 3]


@pytest.mark.parametrize("argv", [["--executor", "ray"], None])
def test_without_the_distributed_extra_the_ray_paths_name_it(argv, tmp_path, capsys, monkeypatch):
    """run_jobs.py --executor ray and tune.py without Ray: exit 2 naming the extra, before anything runs."""
    import softpvtol_gym.baselines.util.extras as extras
    from softpvtol_gym.baselines.commands.tune import main as tune_main

    real = extras.installed

    def no_ray(name):
        return name.split(".")[0] not in ("ray", "optuna") and real(name)

    monkeypatch.setattr(extras, "installed", no_ray)
    with pytest.raises(SystemExit) as exc:
        if argv is None:
            tune_main(["--out", str(tmp_path / "best.yml")])
        else:
            run_jobs_main([*argv, "--spec", str(_spec(tmp_path)), "--root", str(tmp_path / "root")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "'distributed' extra" in err and "softpvtol-gym[distributed]" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "root").exists()
