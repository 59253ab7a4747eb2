"""The leaderboard as a list of independent jobs, and a local runner for it.

A :class:`Job` is one (policy, action mode, task, training tier, seed): a learned policy is trained
(:func:`softpvtol_gym.baselines.training.loop.train`) and then evaluated on every evaluation tier; an analytic policy is
only evaluated. :func:`run_job` is a pure function of the job and the output root (no shared state),
so any executor can run the list: :func:`run_jobs` takes anything with ``concurrent.futures``'
``submit`` / ``Future.result`` interface: ``ProcessPoolExecutor`` locally, or
:class:`softpvtol_gym.baselines.leaderboard.ray_executor.RayExecutor` (Ray tasks on a local instance or a cluster,
writing into a file system that every node shares; ``check_root=True`` makes each task check that it does).

Job outputs (``<root>/<job.name>/``): ``eval.json`` (per evaluation tier, the episode list of
:func:`softpvtol_gym.baselines.evaluation.run_episodes` on the job's own *test* episodes under ``eval``; a learned
cell listed with ``also_evaluated_on`` is evaluated on those tasks too, under ``eval_other_tasks``: task -> tier ->
episodes, so that a policy trained on ``track_random`` is scored on ``track_paper``, which it never
saw; the *selection* episodes, disjoint seeds on which the headline picks each side's strongest entry, under
``selection``: task -> tier -> episodes; every test episode carries the run's per-robot compute on its task and
tier, ``compute_us_single``, measured in a pass of its own,
:func:`~softpvtol_gym.baselines.evaluation.per_robot_compute_us`; ``inference``: the forward pass a learned
job was scored with), and for learned policies the run directory contents that the leaderboard needs (the final model
in the safe checkpoint format: ``model.safetensors``, ``model.json``, ``vecnormalize.json``,
``config.yaml`` and the manifest ``checkpoint.json``, plus ``evaluations.json``). A job whose
``eval.json`` holds every (task, tier) it is evaluated on is done and skipped, so an interrupted list
can simply be re-run, and a task added to ``also_evaluated_on`` only evaluates what is missing.

A learned policy is evaluated through :class:`~softpvtol_gym.baselines.training.policy.LearnedPolicy`'s default,
the lean forward pass (:class:`~softpvtol_gym.baselines.training.lean.LeanMLPPolicy`): an episode's actions do not
depend on how many episodes are evaluated beside it (the spec's ``evaluation.inference``, or ``run-jobs
--inference torch``, picks SB3's torch forward instead).

Analytic entries (the spec's ``analytic`` list, or the older ``passivity`` list whose entries are all of kind
``passivity``) have a ``kind``: ``passivity`` (:class:`softpvtol_gym.PassivityPolicy` with the entry's
``allocation`` and ``loop``) or ``mpc`` (``softpvtol_gym.MPCPolicy.from_env(env, **options)``, imported only
when such a job runs); every entry gets the same ``evaluation.episodes`` episodes.

A result is *stale* for a (task, tier) in up to five parts (:func:`stale_parts`): ``test`` when it lacks the
test episodes, when they lack the timing of :data:`~softpvtol_gym.baselines.evaluation.TIMING_METRICS` (results
from before the windowed metrics) or come in another number than the job asks for; ``selection`` likewise for the
selection episodes; ``compute`` when the test episodes lack ``compute_us_single`` or the result's ``compute_pass``
is not how the pass is measured now (:data:`~softpvtol_gym.baselines.evaluation.COMPUTE_PASS`); ``metrics`` when
the episodes are all there, timed, but lack a metric the evaluator records since
(:data:`~softpvtol_gym.baselines.evaluation.EPISODE_METRICS`, e.g. ``fraction_within_1cm``): the test and
selection episodes are run again without timing, every recorded metric must come out the same to the last bit (else
a ConfigError says to re-evaluate the job), and only the new metrics are added, the wall-time figures kept;
``roundoff`` when an analytic job's test episodes there are all one outcome (a deterministic task and tier) and the
result lacks its round-off probe (:func:`~.episodes.roundoff_episodes`: the same episode from starts moved by
:data:`~.episodes.ROUNDOFF_SHIFT_M`, under ``roundoff``: task -> tier -> episodes), which tells the leaderboard
whether a difference there is larger than what round-off alone can move. A learned result scored with another
forward pass than the job's ``inference`` (results from before the lean path record none) is stale in the first
three. Only the stale parts are run again (with the committed model: a learned job with a model is never trained
again); ``rescore=True`` (``run-jobs --rescore``) runs only those, of jobs that have a result, and refuses to train.

The spec is validated before any job runs (:func:`load_spec`: unknown keys, wrong types, unknown tasks,
tiers, kinds or action modes, episode counts out of range are errors naming the key); job names are safe
slugs and every output path is checked to stay under the root.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import shutil
import socket
import sys
import time
import uuid
from concurrent.futures import Executor, as_completed
from pathlib import Path

from softpvtol_gym.baselines.checkpoints.manifest import MANIFEST_FILE, MODEL_FILE, MODEL_FILES
from softpvtol_gym.baselines.checkpoints.store import legacy_files
from softpvtol_gym.baselines.config.hyperparams import (
    CONFIG_FILE_NAME,
    apply_overrides,
    load_hyperparams,
)
from softpvtol_gym.baselines.config.recipes import load_recipe, recipe_config_fields
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import (
    COMPUTE_PASS,
    COMPUTE_SINGLE,
    EPISODE_METRICS,
    TIMING_METRICS,
    identical_episodes,
    per_robot_compute_us,
)
from softpvtol_gym.baselines.leaderboard.distilled import RECORD_FILES, recorded_seconds, train_distilled
from softpvtol_gym.baselines.leaderboard.episodes import (
    ROUNDOFF_STARTS,
    job_episodes,
    job_policy,
    roundoff_episodes,
    with_new_metrics,
)
from softpvtol_gym.baselines.leaderboard.spec import (
    INFERENCE,
    SPEC_FILE,
    analytic_entries,
    distilled_folder,
    is_learned,
    load_spec,
    selection_seed,
)
from softpvtol_gym.baselines.training.imitation import source_overrides
from softpvtol_gym.baselines.training.loop import EVALUATIONS_FILE, train
from softpvtol_gym.baselines.util.args import interrupted, io_error_message
from softpvtol_gym.baselines.util.atomic import atomic_copy, atomic_write_text
from softpvtol_gym.baselines.util.paths import Layout, check_slug, relative_to_root, under
from softpvtol_gym.baselines.util.safe_load import loads_json

#: the jobs' run directories by default: ``./results/leaderboard_runs`` (a checkout's scripts pass
#: ``results/leaderboard_runs``)
RUNS_DIR = Layout().runs
EVAL_FILE = "eval.json"
#: written into the job root while run_jobs(check_root=True) runs (see check_shared_root)
ROOT_TOKEN_FILE = ".run_jobs.token"


@dataclasses.dataclass(frozen=True)
class Job:
    """One leaderboard job. ``policy``: "ppo", "distilled" or an analytic entry's name ("passivity-paper", "mpc",
    ...)."""

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
    loop: str | None = None         # passivity variants: their PassivityController loop (control.LOOPS)
    other_eval_tasks: tuple = ()    # tasks it is evaluated on besides its own (learned cells: also_evaluated_on)
    hp: tuple = ()                  # learned cells: "key=value" overrides of the mode's PPO entry (train.py --hp)
    kind: str = "passivity"         # analytic entries: "passivity" or "mpc" (ANALYTIC_KINDS); ignored for "ppo"
    options: tuple = ()             # mpc entries: (name, value) pairs passed to MPCPolicy.from_env
    recipe: str | None = None       # learned cells: the training recipe (data/hyperparams/recipes.yml), or None
    selection_episodes: int = 0     # held-out episodes to choose the headline's entries on (0: none)
    selection_seed: int = 0         # their first seed (disjoint from the test episodes')
    inference: str = "lean"         # learned cells: the forward pass they are scored with (spec.INFERENCE)
    teacher: str | None = None      # distilled cells: the teacher controller (training.teachers.TEACHERS)
    variant: str | None = None      # distilled cells: the name that tells two cells of one teacher apart, or None
    distill_options: tuple = ()     # distilled cells: (name, value) pairs of DistillConfig settings
    init_from: str | None = None    # fine-tuning cells: the distilled cell whose student of this seed PPO starts from
    imitation: tuple = ()           # fine-tuning cells: (name, value) pairs of the imitation term (RunConfig.imitation)

    @property
    def eval_tasks(self) -> tuple:
        """Every task the job is evaluated on: its own first."""
        return (self.task, *self.other_eval_tasks)

    @property
    def name(self) -> str:
        """The job's folder under the root: built from safe slugs only (checked here)."""
        if self.policy == "ppo":
            for what, v in (("action mode", self.action_mode), ("task", self.task), ("tier", self.train_tier)):
                check_slug(v, f"the {what} of a job")
            if self.recipe is not None:
                check_slug(self.recipe, "the recipe of a job")
                return f"ppo-{self.recipe}_{self.task}_{self.train_tier}/seed_{int(self.seed)}"
            return f"ppo_{self.action_mode}_{self.task}_{self.train_tier}/seed_{int(self.seed)}"
        if self.policy == "distilled":
            parts = [self.teacher, self.task, self.train_tier] + ([self.variant] if self.variant else [])
            for v in parts:
                check_slug(v, "the teacher, task, tier or variant of a distilled job")
            folder = distilled_folder({"teacher": self.teacher, "variant": self.variant, "task": self.task,
                                       "tier": self.train_tier})
            return f"{folder}/seed_{int(self.seed)}"
        check_slug(self.policy, "a passivity entry's name")
        check_slug(self.task, "the task of a job")
        return f"{self.policy}_{self.task}"

    @property
    def learned(self) -> bool:
        return is_learned(self.policy)

    def folder(self, root: Path) -> Path:
        """``<root>/<name>``, refused if it would leave ``root``."""
        return under(root, self.name, "job folder")


def load_jobs(spec_path: Path = SPEC_FILE, inference: str | None = None) -> list[Job]:
    """The job list of a leaderboard spec (``softpvtol_gym/baselines/data/leaderboard.yml``); ``inference``: the
    forward pass of the learned jobs (default: the spec's ``evaluation.inference``, else ``lean``)."""
    spec = load_spec(spec_path)
    ev = spec["evaluation"]
    inference = ev.get("inference", "lean") if inference is None else inference
    if inference not in INFERENCE:
        raise ConfigError(f"inference must be one of {list(INFERENCE)}, got {inference!r}")
    common = dict(eval_tiers=tuple(ev["tiers"]), eval_episodes=int(ev["episodes"]), eval_seed=int(ev["seed"]),
                  selection_episodes=int(ev.get("selection_episodes", 0)), selection_seed=selection_seed(ev))
    jobs = []
    for task in spec["tasks"]:
        for p in analytic_entries(spec):
            own = common
            if p["kind"] == "passivity":
                jobs.append(Job(policy=p["name"], action_mode="actuators", task=task, train_tier=None, seed=0,
                                allocation=p["allocation"], loop=p.get("loop", p["allocation"]), **own))
            else:
                jobs.append(Job(policy=p["name"], action_mode="actuators", task=task, train_tier=None, seed=0,
                                kind=p["kind"], options=tuple(sorted((k, _hashable(v))
                                                                     for k, v in p.get("options", {}).items())),
                                **own))
    for cell in spec["trained"]:
        for seed in spec["seeds"]:
            jobs.append(Job(policy="ppo", action_mode=cell["action_mode"], task=cell["task"], train_tier=cell["tier"],
                            seed=int(seed), timesteps=int(cell["timesteps"]),
                            other_eval_tasks=tuple(cell.get("also_evaluated_on", ())),
                            hp=tuple(cell.get("hp", ())), recipe=cell.get("recipe"), inference=inference,
                            init_from=cell.get("init_from"),
                            imitation=tuple(sorted((cell.get("imitation") or {}).items())), **common))
    for cell in spec.get("distilled", []):
        for seed in spec["seeds"]:
            mode = "actuators" if cell.get("options", {}).get("residual_on") is None else "residual"
            jobs.append(Job(policy="distilled", action_mode=mode, task=cell["task"], train_tier=cell["tier"],
                            seed=int(seed), other_eval_tasks=tuple(cell.get("also_evaluated_on", ())),
                            teacher=cell["teacher"], variant=cell.get("variant"),
                            distill_options=tuple(sorted((k, _hashable(v))
                                                         for k, v in cell.get("options", {}).items())),
                            inference=inference, **common))
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ConfigError(f"leaderboard spec {spec_path}: two jobs would share the folders {dup}")
    return jobs


def _hashable(v):
    return tuple(v) if isinstance(v, list) else v


# ----------------------------------------------------------------------------------------- jobs
def read_eval(path: Path) -> dict:
    """A job's eval.json, checked enough to be used (ConfigError naming the file otherwise)."""
    try:
        rec = loads_json(Path(path).read_text(), str(path))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path} is not readable JSON ({exc}); delete it to re-run the job") from None
    if (not isinstance(rec, dict) or not isinstance(rec.get("job"), dict) or not isinstance(rec.get("eval"), dict)
            or "checkpoint" not in rec or "train_seconds" not in rec):
        raise ConfigError(f"{path} is not a job result (expected job, checkpoint, train_seconds and eval); delete it "
                          f"to re-run the job")
    return rec


def _checkpoint_field(out: Path, base: Path | None) -> str:
    """The final model's path as recorded in ``eval.json``: relative to ``base`` (default: the current
    directory) where it lies under it."""
    return relative_to_root(out / MODEL_FILE, Path.cwd() if base is None else base)


def run_job(job: Job, root: Path = RUNS_DIR, reevaluate: bool = False, base: Path | None = None,
            train_missing: bool = True) -> dict:
    """Train (learned policies) and evaluate one job; writes ``<root>/<job.name>/eval.json``.

    A learned job whose final model exists (a checkpoint folder that verifies) is not trained again, only
    evaluated; ``reevaluate=True`` re-runs the evaluation of a finished job (after a change of the env or
    controller code); otherwise only the stale parts of its evaluations run (:func:`stale_parts`: test episodes,
    selection episodes, the per-robot compute pass), each with a policy of its own.
    ``train_missing=False`` (re-scoring): a learned job without a final model is a ConfigError, not trained.
    Training happens in ``<job>.run/`` (resumed if a run was interrupted, started over if
    it never reached a checkpoint); the final model is copied into the job's folder (manifest last) and
    the training folder removed."""

    out = job.folder(root)
    previous = read_eval(out / EVAL_FILE) if (out / EVAL_FILE).is_file() else None
    if previous is not None and not reevaluate and not stale_evaluations(job, previous):
        return previous
    t0 = time.perf_counter()
    train_seconds = None
    if job.learned and (out / MANIFEST_FILE).is_file():
        train_seconds = recorded_seconds(out) if previous is None else previous["train_seconds"]
    elif job.learned:
        if not train_missing:
            raise ConfigError(f"{out} holds no trained model ({MANIFEST_FILE} is missing); re-scoring never trains: "
                              f"run the job without --rescore to train it")
        if legacy_files(out):
            raise ConfigError(f"{out} holds a model in the earlier pickle-based format ({legacy_files(out)}); convert "
                              f"it once with python baselines/export.py from-sb3 --trust-pickle {out} if you trust it")
        run_dir = under(root, job.name + ".run", "job training folder")
        if job.policy == "distilled":
            train_seconds, kept = train_distilled(job, run_dir), RECORD_FILES
        else:
            train_seconds, kept = _train_ppo(job, run_dir, root), (EVALUATIONS_FILE,)
        for fname in (*MODEL_FILES, *kept, MANIFEST_FILE):  # the manifest last: it marks the copy done
            if (run_dir / fname).is_file():
                atomic_copy(run_dir / fname, out / fname)
        shutil.rmtree(run_dir, ignore_errors=True)  # checkpoints, datasets and TensorBoard logs are not kept
    every = {pair: ("test", "selection", "compute", "roundoff") for pair in _pairs(job)}
    todo = every if previous is None or reevaluate else stale_parts(job, previous)
    kept_test = {} if previous is None else evaluations_of(previous)
    kept_selection = {} if previous is None else selections_of(previous)
    evaluations, selections = {}, {}
    roundoff = {} if previous is None else {t: dict(v) for t, v in previous.get("roundoff", {}).items()}
    for task, tier in _pairs(job):  # a part that is not stale is kept as it is
        parts = todo.get((task, tier), ())
        test = kept_test[task][tier] if "test" not in parts else job_episodes(job, out, task, tier, "test")
        if job.selection_episodes:
            selections.setdefault(task, {})[tier] = (
                kept_selection[task][tier] if "selection" not in parts else
                job_episodes(job, out, task, tier, "selection"))
        if "metrics" in parts:
            test = with_new_metrics(job, out, task, tier, test, "test")
            if job.selection_episodes:
                selections[task][tier] = with_new_metrics(job, out, task, tier, selections[task][tier], "selection")
        if "compute" in parts:
            policy, env_kwargs = job_policy(job, out)
            us = per_robot_compute_us(policy, job.action_mode, task, tier, job.eval_seed, env_kwargs=env_kwargs)
            test = [{**e, COMPUTE_SINGLE: us} for e in test]
        evaluations.setdefault(task, {})[tier] = test
        if "roundoff" in parts:
            roundoff.setdefault(task, {}).pop(tier, None)
            if len(test) > 1 and identical_episodes(test):
                roundoff[task][tier] = roundoff_episodes(job, out, task, tier)
    record = {
        "job": dataclasses.asdict(job),
        "checkpoint": _checkpoint_field(out, base) if job.learned else None,
        "train_seconds": None if train_seconds is None else round(train_seconds, 1),
        "inference": job.inference if job.learned else None,
        "compute_pass": COMPUTE_PASS,
        "eval": evaluations[job.task],
    }
    if job.other_eval_tasks:
        record["eval_other_tasks"] = {task: evaluations[task] for task in job.other_eval_tasks}
    if job.selection_episodes:
        record["selection"] = selections
    roundoff = {t: v for t, v in roundoff.items() if v}
    if roundoff:
        record["roundoff"] = roundoff
    atomic_write_text(out / EVAL_FILE, json.dumps(record, indent=1))
    record["wall_seconds"] = time.perf_counter() - t0
    return record


def _train_ppo(job: Job, run_dir: Path, root: Path) -> float | None:
    """Train a PPO cell's job in ``run_dir`` (resumed if a run was interrupted); its seconds (None if it was
    already trained). A fine-tuning cell (``init_from``) starts from the student of its seed under ``root``, with
    that student's network, normalisation and env options."""
    recipe = None if job.recipe is None else load_recipe(job.recipe)
    fields = ({"algo": "ppo", "action_mode": job.action_mode, "env_options": {}} if recipe is None
              else recipe_config_fields(recipe))
    recipe_hp = [] if recipe is None else list(recipe["hp"])
    start, init_from = [], None
    if job.init_from is not None:
        source_dir = under(root, f"{job.init_from}/seed_{int(job.seed)}", "the student a job fine-tunes")
        if not (source_dir / MANIFEST_FILE).is_file():
            raise ConfigError(f"job {job.name} fine-tunes the student in {source_dir}, which holds none yet; run its "
                              f"distilled job first (python baselines/run_jobs.py --only {job.init_from})")
        source = RunConfig.load(source_dir / CONFIG_FILE_NAME)
        # recorded relative to the working directory where it lies under it (no machine's path in a run's files)
        start, init_from = source_overrides(source), relative_to_root(source_dir, Path.cwd())
        fields["env_options"] = {**source.env_options, **fields["env_options"]}
    hp = apply_overrides(load_hyperparams(fields["algo"], job.action_mode), start + recipe_hp + list(job.hp))
    config = RunConfig(**fields, recipe=job.recipe, task=job.task, tier=job.train_tier,
                       timesteps=job.timesteps, seed=job.seed, n_envs=int(hp.get("n_envs", 16)), hyperparams=hp,
                       overrides=start + recipe_hp + list(job.hp),
                       checkpoint_freq=max(job.timesteps // 4, 1), eval_episodes=5,
                       eval_freq=max(job.timesteps // 10, 1),  # ten points of the learning curves
                       init_from=init_from, imitation=dict(job.imitation) or None)
    run = train(config, run_dir, resume=True)
    return run["seconds"] if run["status"] == "trained" else None


def _pairs(job: Job) -> list[tuple[str, str]]:
    return [(task, tier) for task in job.eval_tasks for tier in job.eval_tiers]


def evaluations_of(record: dict) -> dict:
    """task -> tier -> episodes of a job record (its own task's ``eval`` and ``eval_other_tasks``)."""
    own = record["job"]["task"]
    return {own: record["eval"], **{t: ev for t, ev in record.get("eval_other_tasks", {}).items() if t != own}}


def missing_evaluations(job: Job, record: dict) -> list[tuple[str, str]]:
    """The (task, tier) pairs that ``job`` is evaluated on and its result ``record`` lacks."""
    have = evaluations_of(record)
    return [(task, tier) for task in job.eval_tasks for tier in job.eval_tiers if tier not in have.get(task, {})]


#: the parts of a (task, tier) evaluation that run on their own (:func:`stale_parts`)
PARTS = ("test", "selection", "compute", "metrics", "roundoff")
def selections_of(record: dict) -> dict:
    """task -> tier -> selection episodes of a job record (empty for results without them)."""
    chosen = record.get("selection", {})
    return chosen if isinstance(chosen, dict) else {}


def _fresh(episodes, count: int, keys: tuple = (*EPISODE_METRICS, *TIMING_METRICS)) -> bool:
    """``count`` episodes, each with every one of ``keys`` (default: every metric the evaluator records)."""
    return (isinstance(episodes, list) and len(episodes) == count
            and all(isinstance(e, dict) and all(k in e for k in keys) for e in episodes))


#: what an episode recorded before a metric was added still holds: re-running it adds the new metrics
#: (:func:`stale_parts`' ``metrics``)
_TIMED_CORE = ("return", "rms_position_error", "crashed", "length", *TIMING_METRICS)


def stale_parts(job: Job, record: dict) -> dict[tuple[str, str], tuple[str, ...]]:
    """(task, tier) -> the parts of :data:`PARTS` that ``job``'s result ``record`` lacks or holds stale: ``test``
    (missing, another number than ``job.eval_episodes``, or episodes without a metric of :data:`EPISODE_METRICS` /
    :data:`TIMING_METRICS`), ``selection`` (the same for ``job.selection_episodes``, where the job has them),
    ``compute`` (test episodes without ``compute_us_single``, or a record whose ``compute_pass`` is not
    :data:`~softpvtol_gym.baselines.evaluation.COMPUTE_PASS`; always with ``test``); a learned result scored with
    another forward pass than ``job.inference`` (none recorded: from before the lean path): every part."""
    have, chosen = evaluations_of(record), selections_of(record)
    other_path = job.learned and record.get("inference") != job.inference
    out = {}
    for task, tier in _pairs(job):
        test, selected = have.get(task, {}).get(tier), chosen.get(task, {}).get(tier)
        parts = []
        if other_path or not _fresh(test, job.eval_episodes, _TIMED_CORE):
            parts.append("test")
        if job.selection_episodes and (other_path or not _fresh(selected, job.selection_episodes, _TIMED_CORE)):
            parts.append("selection")
        if "test" in parts or record.get("compute_pass") != COMPUTE_PASS or not all(COMPUTE_SINGLE in e for e in test):
            parts.append("compute")
        if ("test" not in parts and not _fresh(test, job.eval_episodes)) or (
                job.selection_episodes and "selection" not in parts
                and not _fresh(selected, job.selection_episodes)):
            parts.append("metrics")
        if not job.learned and ("test" in parts or (
                len(test) > 1 and identical_episodes(test)
                and not _fresh(record.get("roundoff", {}).get(task, {}).get(tier), len(ROUNDOFF_STARTS),
                               EPISODE_METRICS))):
            parts.append("roundoff")
        if parts:
            out[(task, tier)] = tuple(parts)
    return out


def stale_evaluations(job: Job, record: dict) -> list[tuple[str, str]]:
    """The (task, tier) pairs that ``job`` is evaluated on and whose result in ``record`` is missing or stale in
    any part (:func:`stale_parts`): what re-scoring runs again."""
    return list(stale_parts(job, record))


def reevaluate_job(job: Job, root: Path = RUNS_DIR) -> dict:
    """:func:`run_job` with ``reevaluate=True`` (picklable entry point for executors)."""
    return run_job(job, root, reevaluate=True)


def _run_job_entry(job: Job, root: str, reevaluate: bool = False, root_token: str | None = None,
                   base: str | None = None) -> tuple[str, float]:
    """Executor entry point (process pool, Ray task): one thread for torch per worker process; with
    ``root_token``, first check that ``root`` is the driver's (:func:`check_shared_root`)."""
    import torch

    if root_token is not None:
        check_shared_root(Path(root), root_token)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    run_job(job, Path(root), reevaluate=reevaluate, base=None if base is None else Path(base))
    return job.name, time.perf_counter() - t0


def _rescore_job_entry(job: Job, root: str, reevaluate: bool = False, root_token: str | None = None,
                       base: str | None = None) -> tuple[str, float]:
    """:func:`_run_job_entry` that never trains (``run_jobs(rescore=True)``): a learned job without a model fails."""
    import torch

    if root_token is not None:
        check_shared_root(Path(root), root_token)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    run_job(job, Path(root), reevaluate=reevaluate, base=None if base is None else Path(base), train_missing=False)
    return job.name, time.perf_counter() - t0


# ------------------------------------------------------------------------------ a shared job root
@contextlib.contextmanager
def shared_root_token(root: Path):
    """Write a random token into ``<root>/.run_jobs.token`` while a run lasts (removed afterwards) and
    yield it; tasks check it with :func:`check_shared_root`."""

    token = uuid.uuid4().hex
    path = Path(root) / ROOT_TOKEN_FILE
    atomic_write_text(path, token)
    try:
        yield token
    finally:
        with contextlib.suppress(OSError):
            path.unlink()


def check_shared_root(root: Path, token: str) -> None:
    """ConfigError unless ``root`` as seen by this process is the driver's (it holds the driver's token):
    on a cluster, a node that does not mount the driver's file system would otherwise write its results
    where nobody looks."""
    try:
        seen = (Path(root) / ROOT_TOKEN_FILE).read_text().strip()
    except OSError:
        seen = None
    if seen != token:
        state = "missing" if seen is None else "another run's"
        raise ConfigError(f"the job root {root} on host {socket.gethostname()} is not the driver's (its "
                          f"{ROOT_TOKEN_FILE} is {state}): on a cluster --root must be on a file system that every "
                          f"node mounts at the same path")


#: exception type names of a worker that died under its job (the pool's, Ray's, ours)
WORKER_CRASHES = ("WorkerCrashed", "BrokenProcessPool", "WorkerCrashedError", "NodeDiedError", "LocalRayletDiedError",
                  "ActorDiedError", "OutOfMemoryError")


def _failure_line(exc: BaseException) -> str:
    """One line for a failed job: what a user must fix (ConfigError), a dead worker, or the unexpected error."""
    text = " ".join(str(exc).split())
    if isinstance(exc, ConfigError):
        return text
    if isinstance(exc, OSError) and exc.errno is not None:  # disk full, read-only, permission: the path in words
        return io_error_message(exc)
    if type(exc).__name__ in WORKER_CRASHES:
        return f"worker crashed ({type(exc).__name__}: {text[:300]})"
    return f"{type(exc).__name__}: {text[:300]}"


def run_jobs(jobs: list[Job], executor: Executor, root: Path = RUNS_DIR, reevaluate: bool = False,
             check_root: bool = False, progress: bool = True, base: Path | None = None,
             rerun: str | None = None, entry=None, rescore: bool = False) -> list[str]:
    """Submit every job to ``executor`` (anything with ``submit`` returning futures: a
    :class:`~softpvtol_gym.baselines.leaderboard.process_executor.ProcessPerJobExecutor`, a process pool, a
    :class:`softpvtol_gym.baselines.leaderboard.ray_executor.RayExecutor`); returns the names of the jobs that
    finished, in completion order (the jobs that fine-tune a student, ``init_from``, in a second wave once the
    others are done), printing one line per job (and a progress bar on a terminal, ``progress``). A job
    that fails (a :class:`~softpvtol_gym.baselines.errors.ConfigError`: an unusable checkpoint, a busy folder; a
    worker that was killed: ``worker crashed``; any other error) is reported in one line and the others go on; at
    the end a ConfigError lists the failed jobs and the command that re-runs them (``rerun``; finished jobs are
    skipped then). Interrupted (Ctrl-C, SIGTERM), the KeyboardInterrupt is re-raised with what was kept
    (:func:`softpvtol_gym.baselines.util.args.interrupted`).
    ``check_root``: every job first checks that it sees the same ``root`` as this process (for executors
    on other machines). ``base``: the checkpoint paths in ``eval.json`` are recorded relative to it (default:
    the current directory). ``entry``: the function each job runs in its worker (default :func:`_run_job_entry`;
    another, with the same arguments and ``(name, seconds)`` result, for tests of the executors). ``rescore``: the
    default entry never trains (a learned job without its model fails; :func:`stale_jobs` selects the jobs)."""
    from tqdm import tqdm

    for job in jobs:
        job.folder(root)  # every output path checked before anything runs
    again = f"; rerun: {rerun} (finished jobs are skipped)" if rerun else ""
    done, failed = [], []
    try:
        with contextlib.ExitStack() as stack:
            token = stack.enter_context(shared_root_token(root)) if check_root else None
            base = str((Path.cwd() if base is None else Path(base)).resolve())  # paths in eval.json relative to it
            entry = entry or (_rescore_job_entry if rescore else _run_job_entry)
            # disable=None: a bar on a terminal only (logs get the one line per job below)
            bar = stack.enter_context(tqdm(total=len(jobs), unit="job", file=sys.stderr,
                                           disable=None if progress else True))
            # two waves: the jobs that fine-tune a student start once every other job (their students) is done
            later = [j for j in jobs if getattr(j, "init_from", None) is not None]
            for wave in ([j for j in jobs if j not in later], later):
                futures = {executor.submit(entry, job, str(root), reevaluate, token, base): job for job in wave}
                for fut in as_completed(futures):
                    bar.update(1)
                    try:
                        name, seconds = fut.result()
                    except Exception as exc:  # noqa: BLE001 - one job's failure must not stop the others
                        failed.append(futures[fut].name)
                        bar.write(f"[failed] {futures[fut].name}: {_failure_line(exc)}", file=sys.stderr)
                        continue
                    done.append(name)
                    bar.write(f"[{len(done)}/{len(jobs)}] {name} ({seconds:.0f} s)", file=sys.stdout)
    except KeyboardInterrupt as exc:
        raise interrupted(exc, f"{len(done)} of {len(jobs)} jobs finished and are kept under {root}, "
                               f"{len(jobs) - len(done) - len(failed)} not finished{again}") from None
    if failed:
        raise ConfigError(f"{len(failed)} of {len(jobs)} jobs failed (see above): {', '.join(sorted(failed))}{again}")
    return done


def pending(jobs: list[Job], root: Path = RUNS_DIR) -> list[Job]:
    """The jobs without a result, or whose result is stale (:func:`stale_evaluations`: it lacks a (task, tier) they
    are now evaluated on, or a metric the evaluator now records)."""
    def done(job: Job) -> bool:
        path = job.folder(root) / EVAL_FILE
        return path.is_file() and not stale_evaluations(job, read_eval(path))

    return [j for j in jobs if not done(j)]


def stale_jobs(jobs: list[Job], root: Path = RUNS_DIR) -> tuple[list[Job], list[Job]]:
    """(the jobs with a result that is stale: :func:`stale_evaluations`; the jobs with no result at all): what
    re-scoring runs, and what it leaves to a plain run."""
    stale, unrun = [], []
    for job in jobs:
        path = job.folder(root) / EVAL_FILE
        if not path.is_file():
            unrun.append(job)
        elif stale_evaluations(job, read_eval(path)):
            stale.append(job)
    return stale, unrun

