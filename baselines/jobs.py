"""The leaderboard as a list of independent jobs, and a local runner for it.

A :class:`Job` is one (policy, action mode, task, training tier, seed): a learned policy is trained
(:func:`baselines.training.train`) and then evaluated on every evaluation tier; an analytic policy is
only evaluated. :func:`run_job` is a pure function of the job and the output root (no shared state),
so any executor can run the list: :func:`run_jobs` takes a ``concurrent.futures.Executor``
(``ProcessPoolExecutor`` locally); a cluster engine with the same ``submit`` / ``Future.result``
interface (for example Ray's ``ray.util.ActorPool`` adaptors or Dask's ``distributed.Client``) can run
the same list unchanged, writing into a shared file system.

Job outputs (``<root>/<job.name>/``): ``eval.json`` (per evaluation tier, the episode list of
:func:`baselines.evaluation.run_episodes`), and for learned policies the run directory contents that
the leaderboard needs (``model.zip``, ``vecnormalize.pkl``, ``config.yaml``, ``evaluations.json``).
A job whose ``eval.json`` exists is done and skipped, so an interrupted list can simply be re-run.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
from concurrent.futures import Executor, as_completed
from pathlib import Path

import yaml

REPO_ROOT = Path(__file__).resolve().parents[1]
SPEC_FILE = Path(__file__).resolve().parent / "leaderboard.yml"
RUNS_DIR = Path(__file__).resolve().parent / "results" / "leaderboard_runs"
EVAL_FILE = "eval.json"


@dataclasses.dataclass(frozen=True)
class Job:
    """One leaderboard job. ``policy``: "ppo" or a passivity variant name ("passivity-paper", ...)."""

    policy: str
    action_mode: str
    task: str
    train_tier: str | None          # None for analytic policies
    seed: int
    eval_tiers: tuple
    eval_episodes: int
    eval_seed: int
    timesteps: int = 0
    allocation: str | None = None   # passivity variants: the allocation of their controller

    @property
    def name(self) -> str:
        if self.policy == "ppo":
            return f"ppo_{self.action_mode}_{self.task}_{self.train_tier}/seed_{self.seed}"
        return f"{self.policy}_{self.task}"

    @property
    def learned(self) -> bool:
        return self.policy == "ppo"


def load_jobs(spec_path: Path = SPEC_FILE) -> list[Job]:
    """The job list of a leaderboard spec (``baselines/leaderboard.yml``)."""
    spec = yaml.safe_load(Path(spec_path).read_text())
    ev = spec["evaluation"]
    common = dict(eval_tiers=tuple(ev["tiers"]), eval_episodes=int(ev["episodes"]), eval_seed=int(ev["seed"]))
    jobs = []
    for task in spec["tasks"]:
        for p in spec["passivity"]:
            jobs.append(Job(policy=p["name"], action_mode="actuators", task=task, train_tier=None, seed=0,
                            allocation=p["allocation"], **common))
    for cell in spec["trained"]:
        for seed in spec["seeds"]:
            jobs.append(Job(policy="ppo", action_mode=cell["action_mode"], task=cell["task"], train_tier=cell["tier"],
                            seed=int(seed), timesteps=int(cell["timesteps"]), **common))
    return jobs


def run_job(job: Job, root: Path = RUNS_DIR, reevaluate: bool = False) -> dict:
    """Train (learned policies) and evaluate one job; writes ``<root>/<job.name>/eval.json``.

    A learned job whose ``model.zip`` exists is not trained again, only evaluated; ``reevaluate=True``
    re-runs the evaluation of a finished job (after a change of the env or controller code)."""
    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    from .evaluation import run_episodes

    out = Path(root) / job.name
    previous = json.loads((out / EVAL_FILE).read_text()) if (out / EVAL_FILE).is_file() else None
    if previous is not None and not reevaluate:
        return previous
    t0 = time.perf_counter()
    env_kwargs = {}
    train_seconds = None
    if job.learned and (out / "model.zip").is_file():
        from .training import LearnedPolicy

        policy, _ = LearnedPolicy.load(out / "model.zip")
        train_seconds = None if previous is None else previous["train_seconds"]
    elif job.learned:
        from .config import RunConfig, load_hyperparams
        from .training import LearnedPolicy, train

        run_dir = out.parent / (out.name + ".run")
        hp = load_hyperparams("ppo", job.action_mode)
        config = RunConfig(algo="ppo", action_mode=job.action_mode, task=job.task, tier=job.train_tier,
                           timesteps=job.timesteps, seed=job.seed, n_envs=int(hp.get("n_envs", 16)), hyperparams=hp,
                           checkpoint_freq=max(job.timesteps // 4, 1), eval_freq=max(job.timesteps // 4, 1),
                           eval_episodes=5)
        run = train(config, run_dir, resume=(run_dir / "checkpoints").is_dir())
        train_seconds = run["seconds"]
        policy = LearnedPolicy(run["model"], run["vecnorm"])
        out.mkdir(parents=True, exist_ok=True)
        for fname in ("model.zip", "vecnormalize.pkl", "config.yaml", "evaluations.json"):
            if (run_dir / fname).is_file():
                shutil.copy2(run_dir / fname, out / fname)
        shutil.rmtree(run_dir, ignore_errors=True)  # checkpoints and TensorBoard logs are not kept
    else:
        env_kwargs = {"allocation": job.allocation}
        probe = SoftPVTOLVectorEnv(num_envs=1, action_mode=job.action_mode, task=job.task, **env_kwargs)
        policy = PassivityPolicy.from_env(probe)
    results = {}
    for tier in job.eval_tiers:
        results[tier] = run_episodes(policy, job.action_mode, job.task, tier, job.eval_episodes, job.eval_seed,
                                     env_kwargs=env_kwargs)
    record = {
        "job": dataclasses.asdict(job),
        "checkpoint": (str((out / "model.zip").relative_to(REPO_ROOT)) if job.learned and _inside_repo(out) else
                       (str(out / "model.zip") if job.learned else None)),
        "train_seconds": None if train_seconds is None else round(train_seconds, 1),
        "eval": results,
    }
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f".{EVAL_FILE}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(record, indent=1))
    os.replace(tmp, out / EVAL_FILE)
    record["wall_seconds"] = time.perf_counter() - t0
    return record


def reevaluate_job(job: Job, root: Path = RUNS_DIR) -> dict:
    """:func:`run_job` with ``reevaluate=True`` (picklable entry point for executors)."""
    return run_job(job, root, reevaluate=True)


def _inside_repo(path: Path) -> bool:
    try:
        Path(path).resolve().relative_to(REPO_ROOT)
        return True
    except ValueError:
        return False


def _run_job_entry(job: Job, root: str, reevaluate: bool = False) -> tuple[str, float]:
    """Process-pool entry point: one thread for torch per worker process."""
    import torch

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    run_job(job, Path(root), reevaluate=reevaluate)
    return job.name, time.perf_counter() - t0


def run_jobs(jobs: list[Job], executor: Executor, root: Path = RUNS_DIR, reevaluate: bool = False) -> list[str]:
    """Submit every job to ``executor`` (anything with ``submit`` returning futures); returns the
    names of the jobs that finished, in completion order, printing progress."""
    futures = {executor.submit(_run_job_entry, job, str(root), reevaluate): job for job in jobs}
    done = []
    for fut in as_completed(futures):
        name, seconds = fut.result()
        done.append(name)
        print(f"[{len(done)}/{len(jobs)}] {name} ({seconds:.0f} s)", flush=True)
    return done


def pending(jobs: list[Job], root: Path = RUNS_DIR) -> list[Job]:
    return [j for j in jobs if not (Path(root) / j.name / EVAL_FILE).is_file()]


if __name__ == "__main__":  # pragma: no cover
    sys.exit("use python baselines/run_jobs.py")
