"""Score your own policy on the leaderboard's test episodes and see where it would rank.

    softpvtol score --policy my_controllers:make_policy                   # a module importable from here
    softpvtol score --policy path/to/controller.py:make --task hover --tier nominal --episodes 2
    softpvtol score --policy my_controllers:make_policy --json results/my_policy.json

(From a source checkout, ``python baselines/score.py`` takes the same options.)

``--policy MODULE:FACTORY``: MODULE is a dotted module importable from the current directory, or a path to a
``.py`` file; FACTORY the name of a callable in it. ``FACTORY(env)`` gets a one-env ``SoftPVTOLVectorEnv`` of the
task, tier and ``--action-mode`` being scored and returns an object with a stable-baselines3 ``predict`` (an SB3
model, ``softpvtol_gym.PassivityPolicy``, ...) or a plain callable observation -> action.

It runs the leaderboard's tasks and tiers (``--task`` / ``--tier``, repeatable, for a part of them) on its seeded
test episodes (the first ``--episodes``; default all 20), with the same windowed metrics and statistics (IQM and
95 % stratified-bootstrap CI per window, one run: CIs over episodes) and the per-robot compute (``compute_us_single``:
``predict`` on one observation at a time, in a pass of its own), and prints, per (task, tier, window), its rank
among the committed entries of ``--leaderboard`` (default ``./results/leaderboard.json``) and the strongest of them.
``--json`` writes everything (episodes, rows, ranking). Exit codes: 0 done, 2 bad input (one line; nothing written).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from softpvtol_gym.baselines.config.hyperparams import MAX_EPISODES
from softpvtol_gym.baselines.leaderboard.score import ENTRY, LEADERBOARD_JSON, ranking_markdown, score
from softpvtol_gym.baselines.leaderboard.spec import SPEC_FILE
from softpvtol_gym.baselines.user_policy import load_factory
from softpvtol_gym.baselines.util.args import Parser, check_output_file, command_main, int_arg, refuse_repeated
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.envs.actions import ACTION_MODES


def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", required=True, metavar="MODULE:FACTORY",
                    help="MODULE: a dotted module importable from the current directory, or a path to a .py file; "
                         "FACTORY: a callable in it, FACTORY(env) -> an object with predict, an SB3 model, or a "
                         "callable observation -> action")
    ap.add_argument("--task", action="append", default=None, help="a task to score (repeatable; default: all)")
    ap.add_argument("--tier", action="append", default=None, help="a tier to score (repeatable; default: all)")
    ap.add_argument("--episodes", type=int_arg(1, MAX_EPISODES), default=None,
                    help="the first N of the leaderboard's test episodes (default: all of them)")
    ap.add_argument("--action-mode", choices=ACTION_MODES, default="actuators", help="default: %(default)s")
    ap.add_argument("--leaderboard", type=Path, default=LEADERBOARD_JSON,
                    help="the leaderboard JSON to rank against (default: the committed leaderboard's summary that "
                         "ships with the package)")
    ap.add_argument("--spec", type=Path, default=SPEC_FILE,
                    help="the leaderboard spec (tasks, tiers, test seeds; default: the package's)")
    ap.add_argument("--json", type=Path, default=None, help="write the result here (refuses to overwrite)")
    ap.add_argument("--force", action="store_true", help="overwrite --json if it exists")
    args = ap.parse_args(argv)
    refuse_repeated(ap, "--task", args.task, keyed=False)
    refuse_repeated(ap, "--tier", args.tier, keyed=False)
    if args.json is not None:
        check_output_file(args.json, args.force)
    factory = load_factory(args.policy)
    result = score(factory, tasks=args.task, tiers=args.tier, episodes=args.episodes, action_mode=args.action_mode,
                   leaderboard=args.leaderboard, spec=args.spec, name=f"{ENTRY} ({args.policy})")
    print(ranking_markdown(result))
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(result, indent=1, allow_nan=False))
    return 0


main = command_main("score.py", _main,
                    "``softpvtol score``: your policy on the leaderboard's episodes, ranked among its entries.")
