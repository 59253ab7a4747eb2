"""Train an agent on SoftPVTOL-v0 and compare it with the passivity controller (``softpvtol train``; from a
source checkout ``python train.py``, with the same options).

    python train.py                      # PPO, residual mode, hover, nominal tier (the default agent)
    python train.py --action-mode actuators --task track_paper --tier wind --timesteps 500000 --seed 3
    python train.py --out runs/x --resume    # continue a killed run from its newest checkpoint
    python train.py --hp n_epochs=5 --hp learning_rate=1e-4   # override YAML hyperparameters
    python train.py --device cuda            # the policy on a GPU (the env steps on the CPU)
    python train.py --hp frame_stack=4       # the policy sees the last 4 observations (SB3's VecFrameStack)
    python train.py --env residual_scale=0.4 # an env option, for training and evaluation (docs/baselines.md)
    python train.py --train-env precision_reward_weight=1   # a training-only env option (reward terms, starts)
    python train.py --recipe residual-integral-gated --task track_random   # a named recipe (recipes.yml)
    python train.py --init-from runs/student --tier wind --bc-teacher integral   # fine-tune a distilled student

Hyperparameters come from ``softpvtol_gym/baselines/data/hyperparams/<algo>.yml`` (the entry of the mode's env id:
``SoftPVTOLResidual-v0``, ``SoftPVTOLVirtual-v0``, ``SoftPVTOLActuators-v0``; rl-baselines3-zoo's format);
CLI overrides are recorded in the run's ``config.yaml``. Training runs on the native vector env through
the SB3 adapter with ``torch.set_num_threads(1)``; TensorBoard logs go to ``<out>/tb``; checkpoints
(model weights + VecNormalize statistics + config + env/RNG state, in a format that cannot run code)
are written atomically every ``--checkpoint-freq`` steps. The run ends by evaluating the agent and the
passivity controller on the same held-out seeded episodes (seeds from 1,000,000 on; training uses seeds
below) and prints both.

``--resume`` continues the run in ``--out`` (options left out take the run's saved values; ``--timesteps`` may
extend it; ``--recipe``, if given, must be the one config.yaml records); a run killed before its first
checkpoint starts over with the same command; on a finished run it says so and exits 0. Exit codes: 0 done, 2
bad input or a run directory in use (one line, nothing written or overwritten), 74 an I/O error (disk full,
read-only: one line naming the path; the last checkpoint stays whole), 130 / 143 interrupted by Ctrl-C /
SIGTERM (the last checkpoint is kept; ``--resume`` continues).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.checkpoints.store import checkpoint_candidates, find_checkpoint
from softpvtol_gym.baselines.config.hyperparams import (
    ALGOS,
    CONFIG_FILE_NAME,
    ENV_OPTION_KEYS,
    MAX_EPISODES,
    MAX_N_ENVS,
    MAX_TIMESTEPS,
    TRAIN_SEED_LIMIT,
    TRAINING_ENV_OPTION_KEYS,
    apply_overrides,
    load_hyperparams,
    parse_env_options,
    read_yaml,
)
from softpvtol_gym.baselines.config.recipes import RECIPES_FILE, load_recipe, recipe_config_fields
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, evaluate
from softpvtol_gym.baselines.training.imitation import source_overrides
from softpvtol_gym.baselines.training.loop import prepare, train
from softpvtol_gym.baselines.training.models import DEVICES
from softpvtol_gym.baselines.training.policy import LearnedPolicy
from softpvtol_gym.baselines.training.teachers import TEACHERS
from softpvtol_gym.baselines.util.args import (
    Parser,
    check_output_dir,
    command_main,
    float_arg,
    int_arg,
    interrupted,
    path_arg,
    refuse_repeated,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.locks import DirectoryLock
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.control import LOOPS
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv
from softpvtol_gym.tasks import registered_tasks

RESULT_FILE = "result.json"
DEFAULTS = {"algo": "ppo", "action_mode": "residual", "task": "hover", "tier": "nominal", "seed": 0,
            "checkpoint_freq": 100_000, "eval_freq": 50_000, "eval_episodes": 10}


def build_parser(prog: str = "train.py") -> Parser:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", default=None, choices=ALGOS, help="default: ppo")
    ap.add_argument("--action-mode", default=None, choices=ACTION_MODES, help="default: residual")
    ap.add_argument("--task", default=None, choices=registered_tasks(), help="default: hover")
    ap.add_argument("--tier", default=None, choices=registered_tiers(), help="default: nominal")
    ap.add_argument("--timesteps", type=int_arg(), default=None,
                    help=f"default: n_timesteps of the YAML entry (at most {MAX_TIMESTEPS:,})")
    ap.add_argument("--seed", type=int_arg(), default=None,
                    help=f"training seed in [0, {TRAIN_SEED_LIMIT:,}), default 0")
    ap.add_argument("--n-envs", type=int_arg(), default=None,
                    help=f"default: n_envs of the YAML entry (at most {MAX_N_ENVS:,})")
    ap.add_argument("--out", type=path_arg, default=None,
                    help="run directory (default runs/<algo>_<mode>_<task>_<tier>_s<seed>)")
    ap.add_argument("--resume", action="store_true", help="continue the run in --out from its newest checkpoint")
    ap.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE", help="override a YAML hyperparameter")
    ap.add_argument("--hyperparams", type=Path, default=None, metavar="DIR",
                    help="folder holding <algo>.yml (default: the package's data/hyperparams; a resumed run keeps "
                         "its own)")
    ap.add_argument("--env", action="append", default=[], metavar="KEY=VALUE", dest="env_options",
                    help=f"an env argument of the run's training and evaluation envs, one of {list(ENV_OPTION_KEYS)} "
                         f"(residual mode; recorded in config.yaml as env_options)")
    ap.add_argument("--train-env", action="append", default=[], metavar="KEY=VALUE", dest="train_env_options",
                    help=f"an env argument of the training env only, one of {list(TRAINING_ENV_OPTION_KEYS)} "
                         f"(reward terms and starts; evaluations keep the task's own; recorded as train_env_options)")
    ap.add_argument("--controller-loop", default=None, choices=list(LOOPS),
                    help="the analytic loop under the residual action (residual mode; default: the env's)")
    ap.add_argument("--start-error-curriculum", default=None, metavar="S0,STEPS",
                    help="scale the starts' deviation from the reference from S0 at step 0 linearly to the run's "
                         "start_error_scale (default 1) at STEPS (e.g. 0.2,500000)")
    ap.add_argument("--recipe", default=None, metavar="NAME",
                    help=f"a training recipe of {RECIPES_FILE.name} (algo, action mode, base loop, env and training "
                         f"options, hyperparameter overrides); the other options change it")
    ap.add_argument("--init-from", type=Path, default=None, metavar="RUN",
                    help="start from the policy of this run (e.g. a `softpvtol distill` student): its weights and "
                         "observation statistics, its action mode, env options and network; task and tier default "
                         "to its own")
    ap.add_argument("--bc-teacher", default=None, choices=TEACHERS,
                    help="with --init-from: an imitation term toward this teacher after each PPO update, its weight "
                         "decaying linearly to 0 (docs/baselines.md, 'Fine-tuning a student')")
    ap.add_argument("--bc-weight", type=float_arg(0.0, 1e6, lo_open=True), default=None,
                    help="the imitation term's initial weight (default 1)")
    ap.add_argument("--bc-decay-steps", type=int_arg(1), default=None,
                    help="steps over which the weight decays to 0 (default: half of --timesteps)")
    ap.add_argument("--bc-epochs", type=int_arg(1, 100), default=None,
                    help="passes of the imitation term over each rollout (default 1)")
    ap.add_argument("--checkpoint-freq", type=int_arg(), default=None, help="env steps between checkpoints (100,000)")
    ap.add_argument("--eval-freq", type=int_arg(), default=None,
                    help="env steps between periodic evaluations (50,000, or the recipe's eval_freq)")
    ap.add_argument("--eval-episodes", type=int_arg(), default=None,
                    help=f"episodes per evaluation (10; 0: none; at most {MAX_EPISODES:,})")
    ap.add_argument("--device", default="cpu", choices=DEVICES,
                    help="where the policy trains (the env always steps on the CPU): cpu (default; fastest for the "
                         "small MLPs here), cuda (an error without a CUDA GPU), auto (cuda if there is one)")
    ap.add_argument("--no-progress-bar", action="store_true")
    return ap


def _saved_config(out: Path) -> RunConfig | None:
    """The config of an existing run (its config.yaml, else its newest checkpoint's), or None if it has no
    complete one (a run killed before its first checkpoint starts over); a ConfigError if its configs are files
    that are not even YAML text (corrupt, or not a run's: resuming would train a new run over the folder's
    files)."""
    failed = None
    for path in [out / CONFIG_FILE_NAME, *(c / CONFIG_FILE_NAME for c in checkpoint_candidates(out))]:
        if path.is_file():
            try:
                return RunConfig.load(path)
            except ConfigError:
                try:
                    read_yaml(path, "run config")  # YAML, but not a whole config: the run starts over
                except ConfigError as exc:
                    failed = failed or exc
    if failed is not None:
        raise ConfigError(f"--resume: the run in {out} has no readable config ({failed}); nothing was changed: "
                          f"fix or remove it, or train into another --out")
    return None


def make_config(args, ap: Parser) -> tuple[RunConfig, Path]:
    """The run's config and directory from the command line (and, with --resume, the run's saved config)."""
    for name, lo in (("timesteps", 1), ("n_envs", 1), ("checkpoint_freq", 1), ("eval_freq", 1), ("eval_episodes", 0)):
        v = getattr(args, name)
        if v is not None and v < lo:
            ap.error(f"--{name.replace('_', '-')} must be >= {lo}, got {v}")
    if args.seed is not None and not 0 <= args.seed < TRAIN_SEED_LIMIT:
        ap.error(f"--seed must be in [0, {TRAIN_SEED_LIMIT}) (evaluation seeds start at {EVAL_SEED_OFFSET}), "
                 f"got {args.seed}")
    for flag, items in (("--hp", args.hp), ("--env", args.env_options), ("--train-env", args.train_env_options)):
        refuse_repeated(ap, flag, items)
    given = {k: getattr(args, k) for k in DEFAULTS if getattr(args, k) is not None}
    recipe = load_recipe(args.recipe) if args.recipe is not None else None
    base = dict(DEFAULTS)
    source = _source_config(args, ap)
    if source is not None:
        base.update(algo=source.algo, action_mode=source.action_mode, task=source.task, tier=source.tier)
        for key in ("algo", "action_mode"):
            if key in given and given[key] != getattr(source, key):
                ap.error(f"--{key.replace('_', '-')} {given[key]} differs from the --init-from run's "
                         f"{getattr(source, key)}; a fine-tuned run keeps its policy's interface (leave it out)")
    if recipe is not None:
        base.update(algo=recipe["algo"], action_mode=recipe["action_mode"])
        if recipe["eval_freq"] is not None:  # the recipe's evaluation period (--eval-freq overrides it)
            base["eval_freq"] = recipe["eval_freq"]
        for key in ("algo", "action_mode"):
            if key in given and given[key] != recipe[key]:
                ap.error(f"--{key.replace('_', '-')} {given[key]} contradicts --recipe {args.recipe} ({key} "
                         f"{recipe[key]}); leave it out")
    pick = {**base, **given}
    default_name = ("{algo}_{action_mode}_{task}_{tier}_s{seed}" if args.recipe is None
                    else f"{args.recipe}_{{task}}_{{tier}}_s{{seed}}")
    out = args.out or Path("runs") / default_name.format(**pick)
    if out.exists() and not out.is_dir():
        ap.error(f"--out {out} is a file; expected a run directory")
    env_options = parse_env_options(args.env_options)
    train_env_options = parse_env_options(args.train_env_options, TRAINING_ENV_OPTION_KEYS, "--train-env")
    curriculum = _parse_curriculum(args.start_error_curriculum, ap)
    fields = recipe_config_fields(recipe) if recipe is not None else {
        "controller_loop": None, "env_options": {}, "train_env_options": {}, "start_error_curriculum": None}
    recipe_hp = list(recipe["hp"]) if recipe is not None else []
    saved = None
    if args.resume:
        if not out.is_dir():
            ap.error(f"--resume: run directory {out} does not exist")
        saved = _saved_config(out)
    if saved is not None:
        for key in ("algo", "action_mode", "task", "tier", "seed"):
            if key in given and given[key] != getattr(saved, key):
                raise ConfigError(f"--resume: {key} of the run in {out} is {getattr(saved, key)!r}, the command asks "
                                  f"for {given[key]!r}; resume with the run's own settings (or leave the option out)")
        pick = {**{k: getattr(saved, k) for k in DEFAULTS}, **given}
        hp = apply_overrides(saved.hyperparams, args.hp)
        overrides = list(saved.overrides)
        if args.n_envs is not None and args.n_envs != saved.n_envs:
            hp["n_envs"] = args.n_envs  # refused below (a run keeps its n_envs), naming both
        timesteps = args.timesteps if args.timesteps is not None else saved.timesteps
        if args.timesteps is not None and args.timesteps != saved.timesteps:
            overrides.append(f"n_timesteps={args.timesteps}")
        n_envs = args.n_envs if args.n_envs is not None else saved.n_envs
        env_options = {**saved.env_options, **env_options}  # a different value is refused below, naming both
        train_env_options = {**saved.train_env_options, **train_env_options}
        curriculum = saved.start_error_curriculum if curriculum is None else curriculum
        controller_loop = args.controller_loop or saved.controller_loop
        if args.recipe is not None and args.recipe != saved.recipe:
            if saved.recipe is None:
                raise ConfigError(f"--resume: the run in {out} records no recipe (made without one, or before runs "
                                  f"recorded theirs), the command asks for --recipe {args.recipe}; resume without "
                                  f"--recipe (the run's saved settings are used, a recipe's included)")
            raise ConfigError(f"--resume: recipe of the run in {out} is {saved.recipe!r}, the command asks for "
                              f"{args.recipe!r}; resume with the run's own recipe (or leave --recipe out)")
        recipe_name = saved.recipe
    else:
        start = source_overrides(source)  # the source run's network and normalisation, for --init-from
        hp = apply_overrides(load_hyperparams(pick["algo"], pick["action_mode"], args.hyperparams),
                             start + recipe_hp + args.hp)
        overrides = start + recipe_hp + list(args.hp)
        if source is not None:
            for key, value in source.env_options.items():
                if env_options.get(key, value) != value:
                    ap.error(f"--env {key}={env_options[key]} differs from the --init-from run's {key}={value}; "
                             f"a fine-tuned run keeps its policy's interface (leave it out)")
            env_options = {**source.env_options, **env_options}
        env_options = {**fields["env_options"], **env_options}
        train_env_options = {**fields["train_env_options"], **train_env_options}
        curriculum = fields["start_error_curriculum"] if curriculum is None else curriculum
        controller_loop = args.controller_loop or fields["controller_loop"] or (
            source.controller_loop if source is not None else None)
        recipe_name = args.recipe
        if args.n_envs is not None:
            overrides.append(f"n_envs={args.n_envs}")
            hp["n_envs"] = args.n_envs
        if args.timesteps is not None:
            overrides.append(f"n_timesteps={args.timesteps}")
        n_envs = hp.get("n_envs", 16)
        timesteps = args.timesteps if args.timesteps is not None else hp.get("n_timesteps", 1_000_000)
    config = RunConfig(algo=pick["algo"], action_mode=pick["action_mode"], task=pick["task"], tier=pick["tier"],
                       timesteps=timesteps, seed=pick["seed"], n_envs=n_envs, hyperparams=hp, overrides=overrides,
                       checkpoint_freq=pick["checkpoint_freq"], eval_freq=pick["eval_freq"],
                       eval_episodes=pick["eval_episodes"], env_options=env_options,
                       train_env_options=train_env_options, start_error_curriculum=curriculum,
                       controller_loop=controller_loop, recipe=recipe_name,
                       init_from=saved.init_from if saved is not None else (
                           None if args.init_from is None else str(args.init_from)),
                       imitation=saved.imitation if saved is not None else _imitation(args, timesteps, ap))
    if args.controller_loop is not None and config.action_mode != "residual":
        ap.error(f"--controller-loop sets the analytic loop under the residual action; the run's action mode is "
                 f"{config.action_mode}, which has none (it would only change the passivity comparison); leave it "
                 f"out, or train --action-mode residual")
    if saved is not None and config.controller_loop != saved.controller_loop:
        raise ConfigError(f"--resume: controller_loop of the run in {out} is {saved.controller_loop!r}, the command "
                          f"asks for {config.controller_loop!r}; resume with the run's own settings")
    return config, out


def _source_config(args, ap: Parser) -> RunConfig | None:
    """The config of the ``--init-from`` run (None without it; with --resume the saved run's own is used)."""
    if args.bc_teacher is None:
        for flag in ("bc_weight", "bc_decay_steps", "bc_epochs"):
            if getattr(args, flag) is not None:
                ap.error(f"--{flag.replace('_', '-')} sets the imitation term, which needs --bc-teacher (and "
                         f"--init-from RUN); pass both, or leave it out")
    if args.init_from is None:
        if args.bc_teacher is not None:
            ap.error("--bc-teacher needs --init-from RUN (the imitation term fine-tunes a run's policy)")
        return None
    try:
        return RunConfig.load(find_checkpoint(args.init_from) / CONFIG_FILE_NAME)
    except (ConfigError, CheckpointError) as exc:
        ap.error(f"--init-from {args.init_from}: {exc}")


def _imitation(args, timesteps: int, ap: Parser) -> dict | None:
    if args.bc_teacher is None:
        return None
    return {"teacher": args.bc_teacher, "weight": 1.0 if args.bc_weight is None else float(args.bc_weight),
            "decay_steps": args.bc_decay_steps or max(1, timesteps // 2),
            "epochs": 1 if args.bc_epochs is None else args.bc_epochs}


def _parse_curriculum(raw: str | None, ap: Parser) -> list | None:
    """``"0.2,500000"`` as ``[0.2, 500000]`` (RunConfig checks the ranges), None for None."""
    if raw is None:
        return None
    parts = raw.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return [float(parts[0]), int(parts[1])]
    except ValueError:
        ap.error(f"--start-error-curriculum must look like S0,STEPS (a number and an integer, e.g. 0.2,500000), "
                 f"got {raw!r}")


def _print_comparison(config: RunConfig, out: Path, report: dict) -> None:
    episodes = report[config.algo]["summary"]["episodes"]
    seed = report["eval_seed"]
    print(f"\n{config.algo.upper()} vs passivity, {config.action_mode} / {config.task} / {config.tier}, "
          f"{episodes} held-out episodes (seed {seed}); run in {out}")
    print(f"{'policy':10s} {'return':>9s} {'rms pos [m]':>12s} {'rms att [rad]':>14s} {'effort':>8s} {'crash':>6s}")
    for name, m in ((config.algo, report[config.algo]["summary"]), ("passivity", report["passivity"]["summary"])):
        print(f"{name:10s} {m['mean_return']:9.1f} {m['mean_rms_position_error']:12.3f} "
              f"{m['mean_rms_attitude_error']:14.3f} {m['mean_control_effort']:8.3f} {m['crash_rate']:6.2f}")


def _main(argv, layout: Layout, prog: str) -> int:
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    config, out = make_config(args, ap)
    check_output_dir(out, "--out")  # before any work: not under /proc, a file, or a read-only place
    try:
        return _train_and_compare(args, config, out)
    except KeyboardInterrupt as exc:
        raise interrupted(exc, f"the run in {out} keeps its last complete checkpoint (none if it stopped before the "
                               f"first; nothing half-written); continue it with the same command and --resume "
                               f"--out {out}") from None


def _train_and_compare(args, config: RunConfig, out: Path) -> int:
    prepared = prepare(config, out, device=args.device)  # bad hyperparameters or device end here: nothing written yet

    cell = (config.action_mode, config.task, config.tier)
    episodes = max(config.eval_episodes, 1)
    kw = config.eval_env_kwargs()

    def passivity_episodes() -> dict:
        probe = SoftPVTOLVectorEnv(num_envs=1, **config.env_kwargs())
        return evaluate(PassivityPolicy.from_env(probe), *cell, episodes, EVAL_SEED_OFFSET + config.seed, env_kwargs=kw)

    with DirectoryLock(out, "run directory"):
        had_result = (out / RESULT_FILE).is_file()
        # the passivity controller's episodes before training: what they compile is compiled before the progress
        # bar starts, so the table follows the last training step at once
        passivity = None if had_result else passivity_episodes()
        run = train(config, out, resume=args.resume, progress_bar=not args.no_progress_bar, prepared=prepared,
                    device=args.device)
        if run["status"] == "finished":
            if had_result:
                print(f"{out} is a finished run ({run['num_timesteps']:,} steps, --timesteps "
                      f"{config.timesteps:,}): nothing to train. Its result: {out / RESULT_FILE}")
                return 0
            print(f"{out} is a finished run ({run['num_timesteps']:,} steps); its {RESULT_FILE} is missing: "
                  f"evaluating it again")
        learned = evaluate(LearnedPolicy(run["model"], run["vecnorm"]), *cell, episodes, EVAL_SEED_OFFSET + config.seed,
                           env_kwargs=kw)
        if passivity is None:  # a run resumed past the result it had
            passivity = passivity_episodes()
        report = {"config": config.to_dict(), "train_seconds": round(run["seconds"], 1),
                  "device": run["model"].device.type,
                  "eval_seed": EVAL_SEED_OFFSET + config.seed, config.algo: learned, "passivity": passivity}
        atomic_write_text(out / RESULT_FILE, json.dumps(report, indent=2))
    _print_comparison(config, out, report)
    return 0


main = command_main("train.py", _main,
                    "``softpvtol train``: one training run (default run directory under ``./runs/``).")

