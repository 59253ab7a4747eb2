"""Evaluate any policy with an SB3 ``predict`` on fixed, seeded SoftPVTOL-v0 episodes; write JSON.

    softpvtol evaluate --policy passivity --task hover --tier wind --episodes 20 --json out.json
    softpvtol evaluate --policy runs/ppo_residual_hover_nominal_s0 --tier mismatch --json out.json

(From a source checkout, ``python baselines/evaluate.py`` takes the same options.)

``--policy``: ``passivity`` (the analytic controller: its loop is the env's default, ``bounded``;
``--controller-loop paper|exact|improved|bounded`` picks another, ``--allocation paper`` the paper's
loop), ``mpc`` (the nonlinear MPC, ``softpvtol_gym.MPCPolicy``, actuators mode; needs the mpc extra;
``--mpc-option KEY=VALUE`` sets an ``MPCOptions`` field, the JSON adds its options and solve times under
``mpc``) or a checkpoint: a run directory, a checkpoint directory or its ``model.safetensors``.
Checkpoints load in the project's safe format (docs/baselines.md, "Loading checkpoints"): nothing is
unpickled. A pickle-based file (an SB3 ``model.zip``, a ``vecnormalize.pkl``) is refused unless
``--trust-pickle`` is given: loading one runs any code it contains, so pass it only for files you
created or trust. A checkpoint's action mode is its own (``--action-mode``, if given, must match it);
task and tier default to the ones it was trained on and may be changed.
Episode i uses seed ``--seed`` + i (default 1,000,000: evaluation seeds never overlap training seeds,
which ``train.py`` keeps below 500,000). At most 10,000 episodes per call (they run together, as one
vector env).

The JSON holds ``episodes`` (each: return, rms_position_error [m] over the whole episode,
rms_position_error_transient [m] over its first quarter, rms_position_error_steady [m] over its last half,
max_position_error_final_5s [m], rms_attitude_error [rad], control_effort, crashed, length and
compute_us_per_step [us]: the policy's own predict time per control step, the per-env share of the batch of
``--episodes`` envs; see ``softpvtol_gym/baselines/evaluation.py``; a window the episode crashed before
reaching the end of is null), ``summary`` (their means, and the crash rate; a window's mean is null where an
episode crashed in it) and the settings. Exit codes: 0 done, 2 bad input (one line; nothing written).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, evaluate
from softpvtol_gym.baselines.training.policy import INFERENCE, LearnedPolicy
from softpvtol_gym.baselines.util.args import Parser, check_output_file, command_main, int_arg, refuse_repeated
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.control import LOOPS
from softpvtol_gym.control.mpc import MPCOptions
from softpvtol_gym.envs.actions import ACTION_MODES
from softpvtol_gym.envs.config import EnvConfig
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv
from softpvtol_gym.policies import MPCPolicy
from softpvtol_gym.tasks import registered_tasks

MAX_EPISODES = 10_000
#: loops that are a policy of their own (actuators mode only), never a residual base controller
POLICY_ONLY_LOOPS = ("extended",)
#: the loops --controller-loop may name in any action mode
RESIDUAL_BASE_LOOPS = tuple(k for k in LOOPS if k not in POLICY_ONLY_LOOPS and k != "ideal")
MAX_SEED = 2**63 - 1


def build_parser(prog: str = "evaluate.py") -> Parser:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, help="'passivity', 'mpc' or a checkpoint path")
    ap.add_argument("--action-mode", choices=ACTION_MODES, default=None,
                    help="default: the checkpoint's; 'actuators' for passivity")
    ap.add_argument("--task", choices=registered_tasks(), default=None,
                    help="default: the checkpoint's; 'hover' for passivity")
    ap.add_argument("--tier", choices=registered_tiers(), default=None,
                    help="default: the checkpoint's; 'nominal' for passivity")
    ap.add_argument("--allocation", choices=("exact", "paper"), default=None,
                    help="allocation of the passivity controller (and of the env in virtual/residual mode); "
                         "default: that of --controller-loop, or exact")
    ap.add_argument("--controller-loop", choices=[k for k in LOOPS if k != "ideal"], default=None,
                    help="analytic loop of the passivity policy and of the residual base controller; default: "
                         "the env's (bounded with the exact allocation, paper with the paper's)")
    ap.add_argument("--mpc-option", action="append", default=[], metavar="KEY=VALUE",
                    help="--policy mpc: an MPCOptions field (repeatable), e.g. --mpc-option horizon=20")
    ap.add_argument("--episodes", type=int_arg(), default=20, help=f"1 to {MAX_EPISODES:,} (default 20)")
    ap.add_argument("--seed", type=int_arg(), default=EVAL_SEED_OFFSET)
    ap.add_argument("--json", type=Path, default=None, help="write the results here (refuses to overwrite)")
    ap.add_argument("--force", action="store_true", help="overwrite --json if it exists")
    ap.add_argument("--inference", choices=INFERENCE, default="lean",
                    help="a checkpoint's forward pass: lean (default: a compiled float64 pass per observation, the "
                         "same actions whatever --episodes) or torch (SB3's predict)")
    ap.add_argument("--trust-pickle", action="store_true",
                    help="also load pickle-based checkpoints (SB3 model.zip, *.pkl): they can run code; only for "
                         "files you created or trust")
    return ap


def _main(argv, layout: Layout, prog: str) -> int:
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    if not 1 <= args.episodes <= MAX_EPISODES:
        ap.error(f"--episodes must be >= 1 and at most {MAX_EPISODES:,} (all episodes run at once, in memory), "
                 f"got {args.episodes}")
    if not 0 <= args.seed <= MAX_SEED - args.episodes:
        ap.error(f"--seed must be >= 0 and seed + episodes at most 2**63 - 1, got {args.seed}")
    if args.json is not None:
        check_output_file(args.json, args.force)
    if args.allocation is not None and args.controller_loop is not None \
            and LOOPS[args.controller_loop]["allocation"] != args.allocation:
        ap.error(f"--controller-loop {args.controller_loop} uses the {LOOPS[args.controller_loop]['allocation']} "
                 f"allocation, not --allocation {args.allocation}; pass one of them")
    refuse_repeated(ap, "--mpc-option", args.mpc_option)
    if args.mpc_option and args.policy != "mpc":
        ap.error(f"--mpc-option is for --policy mpc, got --policy {args.policy}; leave it out or pass --policy mpc")
    env_kwargs = {k: v for k, v in (("allocation", args.allocation), ("controller_loop", args.controller_loop))
                  if v is not None}
    if args.policy == "passivity":
        mode, task, tier = args.action_mode or "actuators", args.task or "hover", args.tier or "nominal"
        if args.controller_loop in POLICY_ONLY_LOOPS and mode != "actuators":
            ap.error(f"--controller-loop {args.controller_loop} is a policy acting on the actuators only, got "
                     f"--action-mode {mode}; pass --action-mode actuators, or another --controller-loop "
                     f"({', '.join(RESIDUAL_BASE_LOOPS)})")
        policy = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode=mode, task=task, **env_kwargs))
        source = "passivity"
    elif args.policy == "mpc":
        mode, task, tier = args.action_mode or "actuators", args.task or "hover", args.tier or "nominal"
        try:
            policy = MPCPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode=mode, task=task, **env_kwargs),
                                        **MPCOptions.parse_items(args.mpc_option))
        except (ImportError, ValueError) as exc:
            ap.error(str(exc))
        source = "mpc"
    else:
        import torch


        # one thread, as train.py and the leaderboard's jobs: the small MLPs run fastest so (several threads
        # made a forward pass 9 ms instead of 0.2 ms on a loaded 2-core machine), and the leaderboard's
        # episodes are reproduced with the same summation order
        torch.set_num_threads(1)
        path = Path(args.policy)
        policy, config = LearnedPolicy.load(path, trust_pickle=args.trust_pickle, inference=args.inference)
        if args.action_mode is not None and args.action_mode != config.action_mode:
            ap.error(f"--action-mode {args.action_mode} does not match the checkpoint's action mode "
                     f"{config.action_mode!r}; leave it out or pass {config.action_mode}")
        mode, task, tier = config.action_mode, args.task or config.task, args.tier or config.tier
        if args.controller_loop in POLICY_ONLY_LOOPS and mode == "residual":
            ap.error(f"--controller-loop {args.controller_loop} cannot be the base controller of a residual "
                     f"checkpoint (it is a policy of its own, acting on the actuators), got {path}; leave "
                     f"--controller-loop out (the checkpoint's own base loop, {config.controller_loop}) or pass one "
                     f"of {', '.join(RESIDUAL_BASE_LOOPS)}")
        if mode == "actuators" and env_kwargs:
            given = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in env_kwargs.items())
            ap.error(f"{given} sets the residual base loop and the virtual mode's allocation; the checkpoint "
                     f"{path} acts on the actuators, so it would change nothing; leave it out")
        source = str(path)
        # the env the checkpoint was trained on (its base loop, its observation options), with the given loop
        env_kwargs = {**config.eval_env_kwargs(), **env_kwargs}
        if "allocation" in env_kwargs and "controller_loop" in env_kwargs and args.controller_loop is None:
            del env_kwargs["controller_loop"]  # --allocation alone: the loop follows the allocation given
    result = evaluate(policy, mode, task, tier, args.episodes, args.seed, env_kwargs=env_kwargs, timing=True)
    s = result["summary"]
    cfg = EnvConfig(action_mode=mode, **env_kwargs)
    report = {"policy": source, "action_mode": mode, "task": task, "tier": tier, "allocation": cfg.resolved_allocation,
              "controller_loop": cfg.resolved_controller_loop,
              "seed": args.seed, **result}
    if args.policy == "mpc":
        report["mpc"] = {"options": {k: v for k, v in vars(policy.options).items()}, "solver": policy.stats}
    print(f"{source}: {mode} / {task} / {tier}, {args.episodes} episodes from seed {args.seed}")
    print(f"  return {s['mean_return']:.1f}  rms position {s['mean_rms_position_error']:.3f} m  "
          f"rms attitude {s['mean_rms_attitude_error']:.3f} rad  effort {s['mean_control_effort']:.3f}  "
          f"crash rate {s['crash_rate']:.2f}")
    steady = s["mean_rms_position_error_steady"]
    print(f"  rms position last half {'crashed' if steady is None else f'{steady:.4f} m'}  "
          f"compute {s['median_compute_us_per_step']:.1f} us/step (per env of {args.episodes})")
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


main = command_main("evaluate.py", _main,
                    "``softpvtol evaluate``: one policy on one task and tier; the JSON report where --json says.")

