"""Issue 15, items 3 and 4: the job list on Ray (``run_jobs.py --executor ray``) gives the process pool's results,
skips finished jobs, reports a failing job in one line; the shared-root check; the Tune search writes a valid
best configuration with its provenance. Ray runs locally with 2 CPUs (no dashboard, a fresh short temp dir)."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from baselines.errors import ConfigError
from baselines.jobs import EVAL_FILE, ROOT_TOKEN_FILE, check_shared_root, load_jobs, run_jobs
from baselines.run_jobs import main as run_jobs_main

# one analytic job and one learned job (a single PPO rollout), two evaluation tiers of 2 episodes
SPEC = ("evaluation: {episodes: 2, seed: 1000000, tiers: [nominal, wind]}\n"
        "passivity: [{name: passivity-exact, allocation: exact}]\n"
        "tasks: [hover]\n"
        "trained: [{action_mode: residual, task: hover, tier: nominal, timesteps: 1}]\n"
        "seeds: [0]\n")
#: files of a learned job that must be byte-identical whichever executor ran it. Not byte-identical even between two
#: pool runs: model.json (it holds the observation space's RNG state, which SB3 leaves unseeded) and the header
#: of model.safetensors (its metadata's key order); the tensors of model.safetensors are compared instead.
SAME_BYTES = ("vecnormalize.json", "evaluations.json", "config.yaml")


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
    return {"job": rec["job"], "eval": rec["eval"]}


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
