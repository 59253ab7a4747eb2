"""Hyperparameter search on Ray Tune: Optuna's TPE sampler proposes, ASHA stops the weak trials early.

    softpvtol tune                                  # PPO, residual, hover, nominal: 20 trials
    softpvtol tune --trials 50 --timesteps 400000 --reports 4 --workers 8
    softpvtol tune --address auto                   # on the cluster of `ray start`
    softpvtol tune --hp n_envs=64 --space my_space.yml --out runs/best.yml

(From a source checkout, ``python baselines/tune.py`` takes the same options.)

The search space (the package's ``tune_space.yml``, or ``--space FILE``; format in that file) spans keys of the
hyperparameter entries of ``softpvtol_gym/baselines/data/hyperparams/<algo>.yml``; the other keys keep the entry's value
(read as ``train.py`` reads it, with ``--hp KEY=VALUE`` overrides). Each trial trains with
:func:`softpvtol_gym.baselines.training.loop.train` (the code of ``train.py``, seed ``--seed``) for ``--timesteps``
env steps in ``--reports`` equal stages; after each stage the deterministic policy is evaluated with
:func:`softpvtol_gym.baselines.evaluation.run_episodes` (the held-out evaluation of ``train.py`` and of the training's
periodic evaluation) on ``--eval-episodes`` seeded episodes, and the metric (``--metric``: mean return,
maximised, or mean RMS position error, minimised) is reported to Tune. ASHA compares trials at those
stages and stops the weaker ones (reduction factor 2, first decision after one stage).

The evaluation episodes are seeded from ``--eval-seed`` (default and least 3,000,000, the project's tuning range):
held out from training (training seeds are below 500,000) and from the episodes ``train.py`` and the leaderboard
report and select on (1,000,000 + i and 2,000,000 + i), so that choosing the best configuration does not bias the
reported comparison.

The best configuration is written (atomically; ``--out`` must not exist unless ``--force``) as YAML, data
only: the full hyperparameter entry, the searched values as ``train.py --hp`` arguments, the objective,
and the provenance (trials, budget per trial, scheduler, search space, seeds, date, git commit, versions,
every trial's result). Exit codes: 0 done, 2 bad input (one line; nothing started), 74 an unwritable path,
130 / 143 interrupted by Ctrl-C / SIGTERM: no best configuration is written from a partial search (one line saying
so), Ray is shut down and the temporary trial folders removed.
Needs the ``distributed`` extra.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import yaml

from softpvtol_gym.baselines.config.hyperparams import (
    ALGOS,
    MAX_EPISODES,
    MAX_TIMESTEPS,
    TRAIN_SEED_LIMIT,
    apply_overrides,
    load_hyperparams,
    read_yaml,
)
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.config.validation import valid_hyperparameter_keys, validate_hyperparams
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import TUNING_SEED, run_episodes, summarize
from softpvtol_gym.baselines.leaderboard.ray_executor import start_ray
from softpvtol_gym.baselines.training.loop import train
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.util.args import (
    Parser,
    Terminated,
    check_output_dir,
    check_output_file,
    command_main,
    int_arg,
    interrupted,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.paths import Layout, data_file
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.registration import ENV_ID
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import registered_tasks

#: the search space shipped with the package (``--space`` passes another)
SPACE_FILE = data_file("tune_space.yml")
#: validation episodes: seeds from here on (training < 500,000; train.py and the leaderboard from 1,000,000)
TUNE_EVAL_SEED = TUNING_SEED
DISTRIBUTIONS = ("loguniform", "uniform", "randint", "choice")
#: keys a search may not span: they are not learning hyperparameters, or the run sets them
UNSEARCHABLE = ("policy", "n_timesteps", "normalize", "policy_kwargs")
METRICS = {"mean_return": "max", "mean_rms_position_error": "min"}
REDUCTION_FACTOR = 2
FORMAT = "softpvtol-gym tune result"


# ------------------------------------------------------------------------------------ the space
def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def load_space(path: Path, algo: str, base: dict) -> dict:
    """The search space of ``algo`` in ``path``: ``{key: {distribution: args}}``, checked (ConfigError naming
    the key): keys must be hyperparameters of ``algo``, every bound and choice must pass
    :func:`~softpvtol_gym.baselines.config.validation.validate_hyperparams` with the rest of ``base``."""
    table = read_yaml(path, "search space")
    if not isinstance(table, dict) or algo not in table:
        raise ConfigError(f"search space {path} must map algorithms to spaces and have an entry {algo!r}, got "
                          f"{sorted(table) if isinstance(table, dict) else table!r}")
    space = table[algo]
    if not isinstance(space, dict) or not space:
        raise ConfigError(f"search space {path}: {algo} must be a non-empty mapping of hyperparameters, got {space!r}")
    valid = [k for k in valid_hyperparameter_keys(algo) if k not in UNSEARCHABLE]
    for key, spec in space.items():
        where = f"search space {path}: {algo}.{key}"
        if key not in valid:
            raise ConfigError(f"{where}: not a searchable {algo.upper()} hyperparameter; valid ones are {valid}")
        if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
            raise ConfigError(f"{where} must be one of {{loguniform|uniform|randint: [low, high]}} or "
                              f"{{choice: [values]}}, got {spec!r}")
        (kind, args), = spec.items()
        if kind == "choice":
            if (not isinstance(args, list) or not args
                    or not all(isinstance(v, (bool, str)) or _number(v) for v in args)):
                raise ConfigError(f"{where}: choice must be a non-empty list of numbers, booleans or strings, "
                                  f"got {args!r}")
            candidates = args
        else:
            ints = kind == "randint"
            if (not isinstance(args, list) or len(args) != 2 or not all(_number(v) for v in args)
                    or (ints and not all(isinstance(v, int) for v in args)) or not args[0] < args[1]
                    or (kind == "loguniform" and args[0] <= 0)):
                need = "integers" if ints else "numbers" + (" > 0" if kind == "loguniform" else "")
                raise ConfigError(f"{where}: {kind} needs [low, high] with low < high, {need}, got {args!r}")
            # uniform and loguniform sample floats (whatever type the bounds are written in)
            candidates = args if ints else [float(v) for v in args]
            if not ints:
                try:
                    validate_hyperparams(algo, {**base, key: float(args[0])})
                except ConfigError:
                    try:
                        validate_hyperparams(algo, {**base, key: int(args[0])})
                    except ConfigError:
                        pass
                    else:
                        raise ConfigError(f"{where}: {key} takes integers but {kind} samples floats; use "
                                          f"{{randint: [low, high]}} or {{choice: [...]}}") from None
        for value in candidates:
            try:
                validate_hyperparams(algo, {**base, key: value})
            except ConfigError as exc:
                raise ConfigError(f"{where}: {value!r} is not a valid value ({exc})") from None
    return space


def tune_domains(space: dict) -> dict:
    """The space as Ray Tune sampling domains (OptunaSearch turns them into Optuna distributions)."""
    from ray import tune

    out = {}
    for key, spec in space.items():
        (kind, args), = spec.items()
        if kind == "loguniform":
            out[key] = tune.loguniform(float(args[0]), float(args[1]))
        elif kind == "uniform":
            out[key] = tune.uniform(float(args[0]), float(args[1]))
        elif kind == "randint":
            out[key] = tune.randint(int(args[0]), int(args[1]) + 1)  # Tune's upper bound is exclusive
        else:
            out[key] = tune.choice(list(args))
    return out


def _plain(value):
    """numpy scalars (what samplers return) as Python numbers, for YAML and the configs."""
    if hasattr(value, "item") and not isinstance(value, (list, dict, str)):
        return value.item()
    return value


# ------------------------------------------------------------------------------------ one trial
def stage_steps(timesteps: int, reports: int) -> list[int]:
    """The cumulative step budgets of a trial's stages: ``timesteps * k // reports``, k = 1..reports."""
    return [max(timesteps * k // reports, 1) for k in range(1, reports + 1)]


def run_trial(sampled: dict, context: dict) -> None:
    """Tune's trainable: train ``context``'s cell with the entry + ``sampled`` in stages, evaluating and
    reporting after each (ASHA may stop it between stages)."""
    import torch
    from ray import tune


    torch.set_num_threads(1)  # one CPU per trial: one torch thread, and one numba thread (the runtime env)
    searched = {k: _plain(v) for k, v in sampled.items()}
    hp = {**context["hyperparams"], **searched}
    run_dir = Path(tune.get_context().get_trial_dir()) / "run"
    for stage, steps in enumerate(stage_steps(context["timesteps"], context["reports"])):
        config = RunConfig(algo=context["algo"], action_mode=context["action_mode"], task=context["task"],
                           tier=context["tier"], timesteps=steps, seed=context["seed"],
                           n_envs=int(hp.get("n_envs", 16)), hyperparams=hp,
                           overrides=[f"{k}={v}" for k, v in searched.items()],
                           checkpoint_freq=MAX_TIMESTEPS, eval_freq=MAX_TIMESTEPS, eval_episodes=0)
        run = train(config, run_dir, resume=stage > 0)
        policy = LearnedPolicy(run["model"], run["vecnorm"])
        summary = summarize(run_episodes(policy, context["action_mode"], context["task"], context["tier"],
                                         context["eval_episodes"], context["eval_seed"]))
        tune.report({"mean_return": summary["mean_return"],
                     "mean_rms_position_error": summary["mean_rms_position_error"],
                     "crash_rate": summary["crash_rate"], "timesteps": int(run["num_timesteps"])})


# ------------------------------------------------------------------------------------ provenance
def git_state(base: Path = Path(".")) -> dict:
    """The commit of the git checkout at ``base`` and whether it has uncommitted changes (None where git cannot
    tell, e.g. outside a checkout)."""
    def git(*args):
        try:
            r = subprocess.run(["git", "-C", str(base), *args], capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return r.stdout.strip() if r.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": None if status is None else bool(status)}


def versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for dist in ("softpvtol-gym", "stable-baselines3", "torch", "numpy", "ray", "optuna"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = None
    return out


def summarize_search(results, metric: str, mode: str) -> tuple[dict | None, list[dict]]:
    """(the best finished trial, every trial) from Tune's ResultGrid, as plain data."""
    trials = []
    for result in results:
        metrics = result.metrics or {}
        frame = result.metrics_dataframe
        trials.append({
            "trial_id": metrics.get("trial_id"),
            "searched": {k: _plain(v) for k, v in (result.config or {}).items()},
            "error": None if result.error is None else " ".join(str(result.error).split())[:500],
            "reports": 0 if frame is None else int(len(frame)),
            "timesteps": metrics.get("timesteps"),
            **{m: metrics.get(m) for m in ("mean_return", "mean_rms_position_error", "crash_rate")},
        })
    scored = [t for t in trials if t["error"] is None and isinstance(t[metric], (int, float))]
    if not scored:
        return None, trials
    # ASHA's survivors ran the whole budget: compare them first, then the metric at the last report
    full = max(t["reports"] for t in scored)
    finalists = [t for t in scored if t["reports"] == full]
    best = (max if mode == "max" else min)(finalists, key=lambda t: t[metric])
    return best, trials


class _TrialLines:
    """A Tune callback printing one line per finished or failed trial."""

    def __new__(cls, total: int, metric: str):
        from ray.tune import Callback

        class TrialLines(Callback):
            def __init__(self):
                self.n = 0

            def _line(self, trial, what: str) -> None:
                self.n += 1
                last = trial.last_result or {}
                value = last.get(metric)
                shown = f"{metric} {value:.3f}" if isinstance(value, (int, float)) else "no result"
                print(f"[{self.n}/{total}] trial {trial.trial_id} {what}: {shown} after "
                      f"{last.get('timesteps', 0):,} steps, {last.get('training_iteration', 0)} reports", flush=True)

            def on_trial_complete(self, iteration, trials, trial, **info):
                self._line(trial, "done")

            def on_trial_error(self, iteration, trials, trial, **info):
                self._line(trial, "failed")

        return TrialLines()


# ------------------------------------------------------------------------------------ the CLI
def build_parser(prog: str = "tune.py") -> Parser:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", default="ppo", choices=ALGOS)
    ap.add_argument("--action-mode", default="residual", choices=ACTION_MODES)
    ap.add_argument("--task", default="hover", choices=registered_tasks())
    ap.add_argument("--tier", default="nominal", choices=registered_tiers())
    ap.add_argument("--trials", type=int_arg(1, 10_000), default=20, help="configurations tried (default 20)")
    ap.add_argument("--timesteps", type=int_arg(1, MAX_TIMESTEPS), default=200_000,
                    help="env steps per trial that ASHA does not stop (default 200,000)")
    ap.add_argument("--reports", type=int_arg(1, 100), default=4,
                    help="stages per trial: evaluated and compared after each (default 4)")
    ap.add_argument("--seed", type=int_arg(0, TRAIN_SEED_LIMIT - 1), default=0,
                    help="training seed of every trial, and the sampler's seed (default 0)")
    ap.add_argument("--eval-episodes", type=int_arg(1, MAX_EPISODES), default=10,
                    help="held-out episodes per evaluation (default 10)")
    ap.add_argument("--eval-seed", type=int_arg(TUNING_SEED), default=TUNE_EVAL_SEED,
                    help=f"seed of the first evaluation episode (default {TUNE_EVAL_SEED:,}; at least {TUNING_SEED:,}: "
                         "the tuning range, apart from the leaderboard's test and selection episodes)")
    ap.add_argument("--metric", default="mean_return", choices=sorted(METRICS),
                    help="objective: mean_return (maximised, default) or mean_rms_position_error (minimised)")
    ap.add_argument("--space", type=Path, default=SPACE_FILE,
                    help="search space YAML (default: the package's tune_space.yml)")
    ap.add_argument("--hyperparams", type=Path, default=None, metavar="DIR",
                    help="folder holding <algo>.yml (default: the package's data/hyperparams)")
    ap.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE",
                    help="override a YAML hyperparameter for every trial (as train.py --hp)")
    ap.add_argument("--workers", type=int_arg(1, 4096), default=None,
                    help="CPUs of the local Ray instance (default: all); not with --address")
    ap.add_argument("--address", default=None, help="an existing Ray cluster: 'auto' or HOST:PORT")
    ap.add_argument("--out", type=Path, default=None,
                    help="best configuration (YAML; default runs/tune_<algo>_<mode>_<task>_<tier>.yml)")
    ap.add_argument("--force", action="store_true", help="overwrite --out")
    ap.add_argument("--storage", type=Path, default=None,
                    help="keep Tune's trial folders here (default: a temporary folder, removed at the end)")
    return ap


def _check_out(ap: Parser, out: Path, force: bool) -> None:
    if out.is_dir():
        ap.error(f"--out {out} is a directory; expected a YAML file path")
    if out.exists() and not force:
        ap.error(f"--out {out} exists; pass --force to overwrite it (nothing was changed)")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        ap.error(f"--out {out}: {parent} is not a writable directory")
    check_output_file(out, force=True, option="--out")  # /proc, read-only mounts: before Ray starts


def _main(argv, layout: Layout, prog: str) -> int:
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    if args.address is not None and args.workers is not None:
        ap.error("--workers with --address: the cluster's CPUs (its `ray start --num-cpus`) are used")
    if args.address is not None and not args.address.strip():
        ap.error("--address must be 'auto' or HOST:PORT, got an empty string")
    out = args.out or Path("runs") / f"tune_{args.algo}_{args.action_mode}_{args.task}_{args.tier}.yml"
    _check_out(ap, out, args.force)
    if args.storage is not None and args.storage.exists() and not args.storage.is_dir():
        ap.error(f"--storage {args.storage} is a file; expected a directory")
    if args.storage is not None:
        check_output_dir(args.storage, "--storage")
    base = apply_overrides(load_hyperparams(args.algo, args.action_mode, args.hyperparams), args.hp)
    validate_hyperparams(args.algo, base)
    space = load_space(args.space, args.algo, base)
    mode = METRICS[args.metric]
    context = {"algo": args.algo, "action_mode": args.action_mode, "task": args.task, "tier": args.tier,
               "seed": args.seed, "hyperparams": base, "timesteps": args.timesteps, "reports": args.reports,
               "eval_episodes": args.eval_episodes, "eval_seed": args.eval_seed}
    # the whole first trial's config, built in memory: what RunConfig refuses is refused before Ray starts
    RunConfig(algo=args.algo, action_mode=args.action_mode, task=args.task, tier=args.tier, timesteps=args.timesteps,
              seed=args.seed, n_envs=int(base.get("n_envs", 16)), hyperparams=base, eval_episodes=0)

    # Tune's default console output names trial folders that are removed at the end (without --storage) and
    # repeats what the one line per trial below says; verbose=0 with the older reporter prints nothing
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    import optuna
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search.optuna import OptunaSearch

    optuna.logging.set_verbosity(optuna.logging.WARNING)


    storage = args.storage.resolve() if args.storage is not None else Path(tempfile.mkdtemp(prefix="softpvtol-tune-"))
    started = _dt.datetime.now(_dt.timezone.utc)
    scheduler = {"time_attr": "training_iteration", "max_t": args.reports, "grace_period": 1,
                 "reduction_factor": REDUCTION_FACTOR}
    # Ctrl-C must stop the search, not end it quietly with a "best" of the trials so far: Tune's own SIGINT
    # handler (which ends fit() normally) is turned off, and a flag catches a signal that Tune swallows anyway
    os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = "1"
    signals: list[int] = []

    def _note(signum, frame):
        signals.append(signum)
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.signal(sig, _note) for sig in (signal.SIGINT, signal.SIGTERM)}
    kept = (f"the trials' folders are kept in --storage {storage}" if args.storage is not None else
            "the trials' temporary folders were removed")
    try:
        with start_ray(address=args.address, num_cpus=args.workers) as resources:
            print(f"Ray Tune: {args.trials} trials x {args.timesteps:,} steps ({args.reports} reports each) on "
                  f"{resources.get('CPU', 0):g} CPUs, one per trial; objective {args.metric} "
                  f"({mode}) on {args.eval_episodes} episodes from seed {args.eval_seed:,}", flush=True)
            trainable = tune.with_resources(tune.with_parameters(run_trial, context=context),
                                            {"cpu": 1})
            tuner = tune.Tuner(
                trainable,
                param_space=tune_domains(space),
                tune_config=tune.TuneConfig(metric=args.metric, mode=mode, num_samples=args.trials,
                                            search_alg=OptunaSearch(seed=args.seed),
                                            scheduler=ASHAScheduler(**scheduler)),
                run_config=tune.RunConfig(name="tune", storage_path=str(storage), verbose=0,
                                          callbacks=[_TrialLines(args.trials, args.metric)]),
            )
            results = tuner.fit()
            if signals:  # swallowed by Tune: the search is partial all the same
                raise Terminated() if signals[-1] == signal.SIGTERM else KeyboardInterrupt()
    except KeyboardInterrupt as exc:
        if signal.SIGTERM in signals and not isinstance(exc, Terminated):
            exc = Terminated()  # Tune re-raises what it caught as a plain KeyboardInterrupt
        raise interrupted(exc, f"the search was stopped before its end, so no best configuration was written (nothing "
                               f"written to {out}); {kept}") from None
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        if args.storage is None:
            shutil.rmtree(storage, ignore_errors=True)
    best, trials = summarize_search(results, args.metric, mode)
    if best is None:
        errors = sorted({t["error"] for t in trials if t["error"]})
        why = f"first error: {errors[0]}" if errors else "none reported an error or a result"
        raise ConfigError(f"no trial finished ({len(trials)} tried; {why}); nothing was written")
    record = {
        "format": FORMAT,
        "cell": {"algo": args.algo, "env_id": ENV_ID, "action_mode": args.action_mode, "task": args.task,
                 "tier": args.tier},
        "best": {
            "objective": best[args.metric],
            "searched": best["searched"],
            "train_py_hp": [f"{k}={v}" for k, v in best["searched"].items()],
            "hyperparameters": {**base, **best["searched"]},
            "timesteps": best["timesteps"],
            "trial_id": best["trial_id"],
        },
        "objective": {"metric": args.metric, "mode": mode,
                      "evaluation": "softpvtol_gym.baselines.evaluation.run_episodes "
                      "(deterministic policy, the evaluation of train.py), mean over episodes",
                      "episodes": args.eval_episodes, "eval_seed": args.eval_seed},
        "budget": {"trials": args.trials, "timesteps_per_trial": args.timesteps, "reports_per_trial": args.reports,
                   "cpus_per_trial": 1, "trials_failed": sum(t["error"] is not None for t in trials),
                   "trials_run_to_the_end": sum(t["reports"] == args.reports for t in trials),
                   "total_timesteps": int(sum(t["timesteps"] or 0 for t in trials)),
                   "wall_seconds": round((_dt.datetime.now(_dt.timezone.utc) - started).total_seconds(), 1)},
        "search": {"searcher": "ray.tune.search.optuna.OptunaSearch (Optuna's default TPE sampler)",
                   "searcher_seed": args.seed, "scheduler": {"ASHAScheduler": scheduler},
                   "space_file": str(args.space), "space": space, "base_overrides": list(args.hp)},
        "seed": args.seed,
        "date": started.isoformat(timespec="seconds"),
        "git": git_state(layout.root),
        "versions": versions(),
        "command": "python baselines/tune.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "trials": trials,
    }

    text = yaml.safe_dump(json.loads(json.dumps(record)), sort_keys=False)  # plain data only
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, text)
    print(f"best {args.metric} {best[args.metric]:.3f} ({best['trial_id']}): train.py --hp "
          + " --hp ".join(record["best"]["train_py_hp"]) + f"\nwritten to {out}", flush=True)
    return 0


main = command_main("tune.py", _main,
                    "``softpvtol tune``: a hyperparameter search (the best configuration under ``./runs/`` by "
                    "default).")

