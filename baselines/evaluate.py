"""Evaluate any policy with an SB3 ``predict`` on fixed, seeded SoftPVTOL-v0 episodes; write JSON.

    python baselines/evaluate.py --policy passivity --task hover --tier wind --episodes 20 --json out.json
    python baselines/evaluate.py --policy runs/ppo_residual_hover_nominal_s0 --tier mismatch --json out.json

``--policy``: ``passivity`` (the analytic controller; ``--allocation paper|exact`` picks its allocation,
default exact) or a checkpoint: a run directory, a checkpoint directory or a ``model.zip`` next to its
``vecnormalize.pkl`` and ``config.yaml``. A checkpoint's action mode is its own (``--action-mode``, if
given, must match it); task and tier default to the ones it was trained on and may be changed.
Episode i uses seed ``--seed`` + i (default 1,000,000: evaluation seeds never overlap training seeds,
which ``train.py`` keeps below 500,000).

The JSON holds ``episodes`` (each: return, rms_position_error [m], rms_attitude_error [rad],
control_effort, crashed, length; see ``baselines/evaluation.py``), ``summary`` (their means, and the
crash rate) and the settings. Exit codes: 0 done, 2 bad input (nothing written).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from baselines.evaluation import EVAL_SEED_OFFSET, evaluate
from softpvtol_gym.envs.core import ACTION_MODES, TASKS, TIERS


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="evaluate.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="'passivity' or a checkpoint path")
    ap.add_argument("--action-mode", choices=ACTION_MODES, default=None,
                    help="default: the checkpoint's; 'actuators' for passivity")
    ap.add_argument("--task", choices=TASKS, default=None, help="default: the checkpoint's; 'hover' for passivity")
    ap.add_argument("--tier", choices=TIERS, default=None, help="default: the checkpoint's; 'nominal' for passivity")
    ap.add_argument("--allocation", choices=("exact", "paper"), default="exact",
                    help="allocation of the passivity controller (and of the env in virtual/residual mode)")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=EVAL_SEED_OFFSET)
    ap.add_argument("--json", type=Path, default=None, help="write the results here (refuses to overwrite)")
    ap.add_argument("--force", action="store_true", help="overwrite --json if it exists")
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    if args.json is not None and args.json.exists() and not args.force:
        ap.error(f"{args.json} exists; pass --force to overwrite it (nothing was written)")
    env_kwargs = {"allocation": args.allocation}
    if args.policy == "passivity":
        from softpvtol_gym import PassivityPolicy
        from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

        mode, task, tier = args.action_mode or "actuators", args.task or "hover", args.tier or "nominal"
        policy = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode=mode, task=task, **env_kwargs))
        source = "passivity"
    else:
        path = Path(args.policy)
        if not path.exists():
            ap.error(f"checkpoint {path} does not exist (expected 'passivity', a run directory, a checkpoint "
                     f"directory or a model.zip)")
        from baselines.config import ConfigError
        from baselines.training import LearnedPolicy

        try:
            policy, config = LearnedPolicy.load(path)
        except (FileNotFoundError, ConfigError) as exc:
            ap.error(str(exc))
        if args.action_mode is not None and args.action_mode != config.action_mode:
            ap.error(f"--action-mode {args.action_mode} does not match the checkpoint's action mode "
                     f"{config.action_mode!r}; leave it out or pass {config.action_mode}")
        mode, task, tier = config.action_mode, args.task or config.task, args.tier or config.tier
        source = str(path)
    result = evaluate(policy, mode, task, tier, args.episodes, args.seed, env_kwargs=env_kwargs)
    s = result["summary"]
    report = {"policy": source, "action_mode": mode, "task": task, "tier": tier, "allocation": args.allocation,
              "seed": args.seed, **result}
    print(f"{source}: {mode} / {task} / {tier}, {args.episodes} episodes from seed {args.seed}")
    print(f"  return {s['mean_return']:.1f}  rms position {s['mean_rms_position_error']:.3f} m  "
          f"rms attitude {s['mean_rms_attitude_error']:.3f} rad  effort {s['mean_control_effort']:.3f}  "
          f"crash rate {s['crash_rate']:.2f}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
