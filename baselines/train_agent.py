"""Train an agent on SoftPVTOL-v0 and compare it with the passivity controller (CLI of ``train.py``).

    python train.py                      # PPO, residual mode, hover, nominal tier (the default agent)
    python train.py --action-mode actuators --task track_paper --tier wind --timesteps 500000 --seed 3
    python train.py --out runs/x --resume    # continue a killed run from its newest checkpoint
    python train.py --hp n_epochs=5 --hp learning_rate=1e-4   # override YAML hyperparameters

Hyperparameters come from ``baselines/hyperparams/<algo>.yml`` (entry ``SoftPVTOL-v0/<action mode>``);
CLI overrides are recorded in the run's ``config.yaml``. Training runs on the native vector env through
the SB3 adapter with ``torch.set_num_threads(1)``; TensorBoard logs go to ``<out>/tb``; checkpoints
(model + VecNormalize statistics + config + env/RNG state) are written atomically every
``--checkpoint-freq`` steps. The run ends by evaluating the agent and the passivity controller on the
same held-out seeded episodes (seeds from 1,000,000 on; training uses seeds below) and prints both.
Exit codes: 0 done, 2 bad input (nothing overwritten).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from softpvtol_gym.envs.core import ACTION_MODES, TASKS, TIERS

from .config import ALGOS, ConfigError, RunConfig, apply_overrides, load_hyperparams
from .evaluation import EVAL_SEED_OFFSET, evaluate

RESULT_FILE = "result.json"


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="train.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", default="ppo", choices=ALGOS)
    ap.add_argument("--action-mode", default="residual", choices=ACTION_MODES)
    ap.add_argument("--task", default="hover", choices=TASKS)
    ap.add_argument("--tier", default="nominal", choices=TIERS)
    ap.add_argument("--timesteps", type=int, default=None, help="default: n_timesteps of the YAML entry")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-envs", type=int, default=None, help="default: n_envs of the YAML entry")
    ap.add_argument("--out", type=Path, default=None,
                    help="run directory (default runs/<algo>_<mode>_<task>_<tier>_s<seed>)")
    ap.add_argument("--resume", action="store_true", help="continue the run in --out from its newest checkpoint")
    ap.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE", help="override a YAML hyperparameter")
    ap.add_argument("--checkpoint-freq", type=int, default=100_000, help="env steps between checkpoints")
    ap.add_argument("--eval-freq", type=int, default=100_000, help="env steps between periodic evaluations")
    ap.add_argument("--eval-episodes", type=int, default=10, help="episodes per evaluation (0: none)")
    ap.add_argument("--no-progress-bar", action="store_true")
    return ap


def make_config(args: argparse.Namespace, ap: argparse.ArgumentParser) -> RunConfig:
    for name in ("timesteps", "n_envs", "checkpoint_freq", "eval_freq"):
        v = getattr(args, name)
        if v is not None and v < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1, got {v}")
    if args.eval_episodes < 0:
        ap.error(f"--eval-episodes must be >= 0, got {args.eval_episodes}")
    if args.seed < 0 or args.seed >= EVAL_SEED_OFFSET // 2:
        ap.error(f"--seed must be in [0, {EVAL_SEED_OFFSET // 2}) (evaluation seeds start at {EVAL_SEED_OFFSET}), "
                 f"got {args.seed}")
    try:
        hp = apply_overrides(load_hyperparams(args.algo, args.action_mode), args.hp)
    except ConfigError as exc:
        ap.error(str(exc))
    overrides = list(args.hp)
    if args.n_envs is not None:
        overrides.append(f"n_envs={args.n_envs}")
        hp["n_envs"] = args.n_envs
    if args.timesteps is not None:
        overrides.append(f"n_timesteps={args.timesteps}")
    timesteps = int(args.timesteps if args.timesteps is not None else hp.get("n_timesteps", 1_000_000))
    try:
        return RunConfig(algo=args.algo, action_mode=args.action_mode, task=args.task, tier=args.tier,
                         timesteps=timesteps,
                         seed=args.seed, n_envs=int(hp.get("n_envs", 16)), hyperparams=hp, overrides=overrides,
                         checkpoint_freq=args.checkpoint_freq, eval_freq=args.eval_freq,
                         eval_episodes=args.eval_episodes)
    except ConfigError as exc:
        ap.error(str(exc))


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    config = make_config(args, ap)
    out = args.out or Path("runs") / f"{config.algo}_{config.action_mode}_{config.task}_{config.tier}_s{config.seed}"
    if args.resume and not out.is_dir():
        ap.error(f"--resume: run directory {out} does not exist")

    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    from .training import LearnedPolicy, train

    try:
        run = train(config, out, resume=args.resume, progress_bar=not args.no_progress_bar)
    except ConfigError as exc:
        ap.error(str(exc))
    cell = (config.action_mode, config.task, config.tier)
    episodes = max(config.eval_episodes, 1)
    learned = evaluate(LearnedPolicy(run["model"], run["vecnorm"]), *cell, episodes, EVAL_SEED_OFFSET + config.seed)
    probe = SoftPVTOLVectorEnv(num_envs=1, **config.env_kwargs())
    passivity = evaluate(PassivityPolicy.from_env(probe), *cell, episodes, EVAL_SEED_OFFSET + config.seed)
    report = {"config": config.to_dict(), "train_seconds": round(run["seconds"], 1),
              "eval_seed": EVAL_SEED_OFFSET + config.seed, config.algo: learned, "passivity": passivity}
    (out / RESULT_FILE).write_text(json.dumps(report, indent=2))
    print(f"\n{config.algo.upper()} vs passivity, {config.action_mode} / {config.task} / {config.tier}, "
          f"{episodes} held-out episodes (seed {EVAL_SEED_OFFSET + config.seed}); run in {out}")
    print(f"{'policy':10s} {'return':>9s} {'rms pos [m]':>12s} {'rms att [rad]':>14s} {'effort':>8s} {'crash':>6s}")
    for name, m in ((config.algo, learned["summary"]), ("passivity", passivity["summary"])):
        print(f"{name:10s} {m['mean_return']:9.1f} {m['mean_rms_position_error']:12.3f} "
              f"{m['mean_rms_attitude_error']:14.3f} {m['mean_control_effort']:8.3f} {m['crash_rate']:6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
