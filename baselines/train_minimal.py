"""Minimal PPO training on SoftPVTOL-v0 and a side-by-side evaluation with the passivity controller.

This is the first, deliberately small version of the training entry point (CLI in ``train.py``):
stable-baselines3 PPO with its default hyperparameters on the native vector env through the SB3
adapter, one seed, then both policies evaluated on the same seeded episodes with one evaluator
(anything with an SB3 ``predict``). Hyperparameter YAMLs, checkpoints/resume, TensorBoard and the
leaderboard are the training issue's next steps.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


from softpvtol_gym import PassivityPolicy
from softpvtol_gym.envs.core import ACTION_MODES, TASKS, TIERS
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

from baselines.evaluation import evaluate

EVAL_SEED_OFFSET = 1_000_000  # evaluation seeds never overlap training seeds (training uses seed + i)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--algo", default="ppo", choices=["ppo"])
    ap.add_argument("--action-mode", default="residual", choices=ACTION_MODES)
    ap.add_argument("--task", default="hover", choices=TASKS)
    ap.add_argument("--tier", default="nominal", choices=TIERS)
    ap.add_argument("--timesteps", type=int, default=200_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-envs", type=int, default=16)
    ap.add_argument("--eval-episodes", type=int, default=10)
    ap.add_argument("--out", type=Path, default=Path("runs/default"))
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    for name in ("timesteps", "n_envs", "eval_episodes"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    model_path = args.out / "model.zip"
    if model_path.exists():
        ap.error(f"{model_path} exists; choose another --out (nothing was overwritten)")

    import torch
    from stable_baselines3 import PPO

    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    torch.set_num_threads(1)
    venv = SoftPVTOLSB3VecEnv(num_envs=args.n_envs, action_mode=args.action_mode, task=args.task, tier=args.tier)
    venv.seed(args.seed)
    model = PPO("MlpPolicy", venv, seed=args.seed, verbose=0, device="cpu")
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.timesteps, progress_bar=False)
    train_s = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    model.save(model_path)
    cell = (args.action_mode, args.task, args.tier)
    learned = evaluate(model, *cell, args.eval_episodes, EVAL_SEED_OFFSET + args.seed)
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode=args.action_mode, task=args.task, tier=args.tier)
    passivity = evaluate(PassivityPolicy.from_env(probe), *cell, args.eval_episodes, EVAL_SEED_OFFSET + args.seed)
    report = {"config": {k: str(v) for k, v in vars(args).items()}, "train_seconds": round(train_s, 1),
              "ppo": learned, "passivity": passivity}
    (args.out / "result.json").write_text(json.dumps(report, indent=2))
    print(f"{'policy':10s} {'return':>9s} {'rms pos [m]':>12s} {'crash':>6s}")
    for name, m in (("ppo", learned), ("passivity", passivity)):
        print(f"{name:10s} {m['mean_return']:9.1f} {m['rms_position_error_m']:12.3f} {m['crash_rate']:6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
