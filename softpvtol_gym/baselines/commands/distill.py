"""Distil a controller into a student network by behaviour cloning and DAgger (``softpvtol distill``; from a
source checkout ``python baselines/distill.py``, with the same options).

    softpvtol distill --teacher integral --task track_random                 # 3 rounds, 16 episodes each
    softpvtol distill --teacher mpc --tier nominal --tier wind --rounds 4 --episodes 32
    softpvtol distill --teacher integral --net-arch 128,128 --out runs/student --resume
    softpvtol distill --teacher integral --precision-scale 0.01     # the fit weighs small errors more
    softpvtol evaluate --policy runs/student --tier wind                      # like any trained run

Round 0 clones the teacher's actions on its own episodes; each further round lets the student fly and the
teacher label what it visits (DAgger); the student is refitted to all rounds' data after each. The student
is a PPO MlpPolicy on the actuators mode with the error integrals observed, saved in the safe checkpoint
format: ``softpvtol evaluate``, the leaderboard and PPO fine-tuning load it like any run. Datasets are cached
under ``<out>/datasets/`` (``--resume`` continues a stopped run with the same options); ``<out>/distill.json``
records the losses and each round's evaluation of the student and the teacher on the same episodes.
Exit codes: 0 done, 2 bad input or a run directory in use, 74 an I/O error, 130 / 143 interrupted (the
datasets collected so far are kept; ``--resume`` continues).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softpvtol_gym.baselines.config.hyperparams import MAX_FRAME_STACK
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.training.distill import DISTILL_FILE, TEACHERS, DistillConfig, distill, distill_table
from softpvtol_gym.baselines.util.args import Parser, check_output_dir, command_main, float_arg, int_arg
from softpvtol_gym.baselines.util.blocks import write_block
from softpvtol_gym.baselines.util.paths import Layout, relative_to_root
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.tasks import registered_tasks

DEFAULTS = DistillConfig()


def build_parser(prog: str = "distill.py") -> Parser:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--teacher", default=DEFAULTS.teacher, choices=TEACHERS,
                    help=f"the controller to imitate (default {DEFAULTS.teacher}; mpc needs the 'mpc' extra)")
    ap.add_argument("--task", default=DEFAULTS.task, choices=registered_tasks(), help=f"default {DEFAULTS.task}")
    ap.add_argument("--tier", action="append", default=None, choices=registered_tiers(), dest="tiers",
                    help="a tier the episodes fly (repeat for several; default nominal)")
    ap.add_argument("--seed", type=int_arg(0), default=DEFAULTS.seed, help="default 0")
    ap.add_argument("--net-arch", default=",".join(map(str, DEFAULTS.net_arch)), metavar="N,N,...",
                    help="the student's hidden layers (default 256,256)")
    ap.add_argument("--rounds", type=int_arg(1), default=DEFAULTS.rounds,
                    help=f"1: behaviour cloning only; each further round is a DAgger round (default {DEFAULTS.rounds})")
    ap.add_argument("--episodes", type=int_arg(1), default=DEFAULTS.episodes,
                    help=f"episodes per task, tier and round (default {DEFAULTS.episodes})")
    ap.add_argument("--epochs", type=int_arg(1), default=DEFAULTS.epochs, help=f"default {DEFAULTS.epochs}")
    ap.add_argument("--batch-size", type=int_arg(1), default=DEFAULTS.batch_size, help=f"default {DEFAULTS.batch_size}")
    ap.add_argument("--learning-rate", type=float_arg(0.0, 1.0, lo_open=True), default=DEFAULTS.learning_rate,
                    help=f"Adam's initial learning rate, decayed linearly to 0 (default {DEFAULTS.learning_rate:g})")
    ap.add_argument("--eval-episodes", type=int_arg(0), default=DEFAULTS.eval_episodes,
                    help=f"student and teacher episodes per task and tier after each round "
                         f"(default {DEFAULTS.eval_episodes})")
    ap.add_argument("--precision-scale", type=float_arg(0.0, 100.0, lo_open=True), default=None, metavar="S",
                    help="weigh each sample by 1 / (S + |position error|) (S in m, e.g. 0.01): the fit spends its "
                         "accuracy where the errors are small (default: every sample the same)")
    ap.add_argument("--wide-fraction", type=float_arg(0.0, 1.0), default=DEFAULTS.wide_fraction, metavar="F",
                    help="the share of each round's episodes that start far from the reference, like track_paper's "
                         "(the env's start_distribution='wide'; default 0)")
    ap.add_argument("--attitude-fraction", type=float_arg(0.0, 1.0), default=DEFAULTS.attitude_fraction, metavar="F",
                    help="the share of each round's episodes that start near the reference but turned (up to 1.2 rad), "
                         "bent and spinning: recovery data (the env's start_distribution='attitude'; default 0)")
    ap.add_argument("--teacher-integral", action=argparse.BooleanOptionalAction, default=DEFAULTS.teacher_integral,
                    help="observe the error integrals as a teacher with integral action integrates them (its error "
                         "clip and limit; default on; --no-teacher-integral: the env's raw integrals)")
    ap.add_argument("--balance-actions", action=argparse.BooleanOptionalAction, default=DEFAULTS.balance_actions,
                    help="divide each action channel's squared error by its variance over the dataset, so that the "
                         "arms' bending inputs weigh as much as the thrusts (default off)")
    ap.add_argument("--teacher-share", type=float_arg(0.0, 1.0), default=DEFAULTS.teacher_share,
                    metavar="P", help="DAgger round k applies the teacher's action at a step with probability P**k "
                                      "(default 0: the student flies alone)")
    ap.add_argument("--teacher-shares", default=None, metavar="B,B,...",
                    help="the teacher's share of each DAgger round, one per round after the first (e.g. 0.5,0.2,0 with "
                         "--rounds 4: a schedule that ends with the student alone), instead of --teacher-share")
    ap.add_argument("--also-task", action="append", default=[], choices=registered_tasks(), dest="also_tasks",
                    help="a further task the episodes fly besides --task (repeat for several): one student for a "
                         "mixture of tasks")
    ap.add_argument("--residual-on", default=None, metavar="LOOP",
                    help="the student is a residual on this passivity loop (e.g. integral: the env's residual mode in "
                         "the actuator space) and learns the correction from the loop's command to the teacher's "
                         "(default: the student commands the actuators)")
    ap.add_argument("--residual-base", default=DEFAULTS.residual_base, choices=("unsaturated", "saturated"),
                    help="with --residual-on: the correction is added to the loop's command as computed (default) or "
                         "to that command clipped to the actuator box (saturated)")
    ap.add_argument("--residual-scale", type=float, default=DEFAULTS.residual_scale, metavar="S",
                    help="with --residual-on: the residual's authority, the correction at +-1 as a fraction of the "
                         "actuator half-ranges, in (0, 100] (default %(default)s: any command of the box; below it "
                         "a bounded residual on the loop)")
    ap.add_argument("--history", type=int_arg(1, MAX_FRAME_STACK), default=DEFAULTS.history, metavar="K",
                    help="the student sees its last K observations, oldest first (a frame stack; default 1: the "
                         "current one)")
    ap.add_argument("--privileged", action="store_true", default=DEFAULTS.privileged,
                    help="the teacher labels (and in round 0 flies) from the noise-free observation of the true "
                         "state, the student learns from the noisy one (needs a --tier with sensor noise)")
    ap.add_argument("--out", type=Path, default=None,
                    help="run directory (default runs/distilled_<teacher>_<task>_s<seed>)")
    ap.add_argument("--resume", action="store_true", help="continue the run in --out (same options)")
    ap.add_argument("--no-progress-bar", action="store_true")
    return ap


def _net_arch(text: str, ap: Parser) -> tuple:
    try:
        sizes = tuple(int(part, 10) for part in text.split(","))
    except ValueError:
        ap.error(f"--net-arch must be comma-separated layer sizes such as 256,256, got {text!r}")
    return sizes


def _shares(text: str | None, ap: Parser) -> tuple:
    if text is None:
        return ()
    try:
        return tuple(float(part) for part in text.split(","))
    except ValueError:
        ap.error(f"--teacher-shares must be comma-separated shares such as 0.5,0.2,0, got {text!r}")


def _main(argv, layout: Layout, prog: str) -> int:
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    tiers = args.tiers or ["nominal"]
    if len(set(tiers)) != len(tiers):
        ap.error(f"--tier repeats a tier ({', '.join(tiers)}); give each once")
    try:
        config = DistillConfig(teacher=args.teacher, task=args.task, tiers=tuple(tiers), seed=args.seed,
                               net_arch=_net_arch(args.net_arch, ap), rounds=args.rounds, episodes=args.episodes,
                               epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.learning_rate,
                               eval_episodes=args.eval_episodes, precision_scale=args.precision_scale,
                               wide_fraction=args.wide_fraction, attitude_fraction=args.attitude_fraction,
                               teacher_integral=args.teacher_integral,
                               balance_actions=args.balance_actions, teacher_share=args.teacher_share,
                               history=args.history, privileged=args.privileged,
                               teacher_shares=_shares(args.teacher_shares, ap), also_tasks=tuple(args.also_tasks),
                               residual_on=args.residual_on, residual_base=args.residual_base,
                               residual_scale=args.residual_scale)
    except ConfigError as exc:
        ap.error(str(exc))
    out = args.out or Path("runs") / f"distilled_{config.teacher}_{config.task}_s{config.seed}"
    if args.resume and not out.is_dir():
        ap.error(f"--resume: run directory {out} does not exist")
    check_output_dir(out, "--out")
    result = distill(config, out, resume=args.resume, progress_bar=not args.no_progress_bar)
    last = result["record"]["rounds"][-1]
    print(f"distilled {config.teacher} into {out} ({last['aggregate']:,} samples, {config.rounds} rounds); "
          f"evaluate it with: softpvtol evaluate --policy {out} --task {config.task}")
    for tier, row in last["evaluation"].items():
        first = result["record"]["rounds"][0]["evaluation"][tier]["teacher"]
        for who, s in (("student", row["student"]), ("teacher", first)):
            steady = s.get("mean_rms_position_error_steady")
            print(f"  {tier:<9} {who:<7} rms position {s['mean_rms_position_error']:.4f} m  last half "
                  f"{'crashed' if steady is None else f'{steady:.4f} m'}  crash rate {s['crash_rate']:.2f}")
    # a checkout's distillation studies hold the tables of the committed students (benchmarks/STUDIES.md)
    page = None if layout.docs is None else layout.root / "benchmarks" / "STUDIES.md"
    source = f"{relative_to_root(out.resolve(), layout.root.resolve())}/{DISTILL_FILE}"
    if page is not None and write_block(f"distill.py {out.name}", source, distill_table(result["record"]), page):
        print(f"wrote the table in {page}")
    return 0


main = command_main("distill.py", _main,
                    "``softpvtol distill``: a student network learned from a controller (behaviour cloning, DAgger).")
