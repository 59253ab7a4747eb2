"""Pack the results into their committed archives, unpack them, or check that the two agree.

    softpvtol results unpack            # ./results/archive/... -> ./results/leaderboard_runs/..., leaderboard.json
    softpvtol results pack              # the other way, after a command wrote results
    softpvtol results check             # exit 1 and one line per difference where they disagree

(From a source checkout, ``python baselines/results.py`` takes the same options; the checkout's scripts and its
tests unpack by themselves.)

The trained runs and the per-episode detail are committed as archives under ``results/archive/``: one
reproducible ``.tar.xz`` per job folder of ``leaderboard_runs/``, ``ablation_runs/`` and ``distill_runs/``, and
``leaderboard.json`` as ``.xz``, thin: its per-episode metrics refer to the jobs' ``eval.json`` (``results/README.md``
says what is where). ``unpack`` writes them back where the
commands read them; it replaces a folder only where its archive changed since it was unpacked, and keeps a
folder that no archive wrote (a job run here and not packed yet) unless ``--force`` is given. ``pack`` drops the
optimizers' state from each finished checkpoint, and a PPO run's critic but a distilled student's (what only
further training needs; the actor and its evaluations are unchanged), and writes the archives that differ.
Exit codes: 0 done (``check``: they agree), 1 ``check`` found differences, 2 bad input (one line).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from softpvtol_gym.baselines.packed_results import differences, pack, unpack
from softpvtol_gym.baselines.util.args import Parser, command_main
from softpvtol_gym.baselines.util.paths import Layout


def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=("unpack", "pack", "check"), help="what to do")
    ap.add_argument("--results", type=Path, default=layout.results, help="the results folder (default: %(default)s)")
    ap.add_argument("--force", action="store_true",
                    help="unpack: also replace folders that no archive wrote (work not packed is lost)")
    args = ap.parse_args(argv)
    if args.force and args.action != "unpack":
        ap.error(f"--force is an option of unpack only, not of {args.action}")
    if not args.results.is_dir():
        ap.error(f"--results {args.results} is not a folder")
    if args.action == "unpack":
        done, kept = unpack(args.results, force=args.force)
        for p in kept:
            print(f"kept {p.target}: no archive wrote it (pack it, or unpack --force to replace it with {p.key})")
        print(f"unpacked {len(done)} archive(s) under {args.results}")
        return 0
    if args.action == "pack":
        changed = pack(args.results)
        print(f"wrote or removed {len(changed)} archive(s) under {args.results / 'archive'}")
        return 0
    found = differences(args.results)
    for line in found:
        print(line)
    print(f"{len(found)} difference(s) between the archives and the results they unpack to")
    return 1 if found else 0


main = command_main("results.py", _main,
                    "``softpvtol results``: the committed archives of the results, packed, unpacked or checked.")
