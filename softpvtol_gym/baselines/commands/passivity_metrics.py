"""Passivity policy on every task x tier of SoftPVTOL-v0 (default env settings, actuators mode).

    softpvtol passivity-metrics [--episodes 10] [--seed 100] [--json results/passivity_metrics.json]
    softpvtol passivity-metrics --render-only --json results/passivity_metrics.json  # table only

In a source checkout ``python baselines/passivity_metrics.py`` writes ``results/passivity_metrics.json``
and refreshes its table in ``docs/control.md``.

For each cell: mean over episodes of the RMS position error [m] over the episode (until it ends) and
the crash rate (fraction of episodes that terminated before the time limit).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from softpvtol_gym import PassivityPolicy
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.evaluation import evaluate
from softpvtol_gym.baselines.util.args import (
    Parser,
    check_output_file,
    command_main,
    int_arg,
    read_json_report,
    refuse_overwrite,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.blocks import check_page, write_block
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.envs.tiers import registered_tiers
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv
from softpvtol_gym.tasks import registered_tasks


def run_cell(task: str, tier: str, episodes: int, seed: int) -> dict:
    env = SoftPVTOLVectorEnv(num_envs=1, task=task, tier=tier, action_mode="actuators")
    m = evaluate(PassivityPolicy.from_env(env), "actuators", task, tier, episodes, seed)["summary"]
    return {"rms_position_error_m": m["mean_rms_position_error"], "crash_rate": m["crash_rate"],
            "episodes": m["episodes"]}


README_SOURCE = "results/passivity_metrics.json"


def metrics_table(report: dict) -> str:
    """The README's task x tier table (mean RMS position error [m] / crash rate) from a report."""
    cells = report["cells"]
    tasks = list(dict.fromkeys(k.split("/")[0] for k in cells))
    tiers = list(dict.fromkeys(k.split("/")[1] for k in cells))
    lines = ["| task | " + " | ".join(tiers) + " |", "|---|" + "---|" * len(tiers)]
    for task in tasks:
        row = [f"{cells[f'{task}/{tier}']['rms_position_error_m']:.2f} / {cells[f'{task}/{tier}']['crash_rate']:.2f}"
               for tier in tiers]
        lines.append(f"| {task} | " + " | ".join(row) + " |")
    return "\n".join(lines)


BLOCK = "passivity_metrics.py"  # the generated block's name (docs/control.md in a checkout)


def _main(argv, layout: Layout, prog: str) -> int:
    default_json = layout.results / "passivity_metrics.json"
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int_arg(1, 10_000), default=10)
    ap.add_argument("--seed", type=int_arg(0, 2**62), default=100)
    ap.add_argument("--json", type=Path, default=default_json, help="the report (default: %(default)s)")
    ap.add_argument("--render-only", action="store_true",
                    help="run nothing: print the table of the report in --json and refresh the generated block")
    ap.add_argument("--page", type=Path, default=None,
                    help=f"Markdown file whose generated table block is refreshed from the default report (default: "
                         f"{layout.doc('control.md')}, where it has the block)")
    ap.add_argument("--force", action="store_true",
                    help="let a run with other settings overwrite the default report")
    args = ap.parse_args(argv)
    # the page's block shows the default run (10 episodes from seed 100) of the default report only
    default_run = (args.render_only or (args.episodes == 10 and args.seed == 100)) and (
        args.json.resolve() == default_json.resolve())
    page = args.page or layout.doc("control.md")
    if args.page is not None:
        check_page(args.page, [(BLOCK, README_SOURCE)])
        if not default_run:
            ap.error(f"--page {args.page}: the page's table shows the default report ({default_json}, 10 episodes "
                     f"from seed 100) only; leave --page out for this run")
    if not args.render_only:
        refuse_overwrite(ap, args, ("episodes", "seed"), [(args.json, default_json, "--json")])
        check_output_file(args.json, force=True, option="--json")  # before running any episode
    if args.render_only:
        report = read_json_report(args.json, "passivity metrics report")
        cells = report.get("cells")
        if not isinstance(cells, dict) or not cells or not all(
                isinstance(k, str) and k.count("/") == 1 and isinstance(c, dict)
                and isinstance(c.get("rms_position_error_m"), (int, float))
                and isinstance(c.get("crash_rate"), (int, float)) for k, c in cells.items()):
            raise ConfigError(f"passivity metrics report {args.json} lacks its 'cells' (task/tier -> "
                              f"rms_position_error_m, crash_rate); write it with softpvtol passivity-metrics")
    else:
        cells, t0 = {}, time.perf_counter()
        for task in registered_tasks():
            for tier in registered_tiers():
                cells[f"{task}/{tier}"] = m = run_cell(task, tier, args.episodes, args.seed)
                print(f"{task:13s} {tier:9s} rms {m['rms_position_error_m']:.3f} m  crash {m['crash_rate']:.2f}",
                      flush=True)
        command = "python baselines/passivity_metrics.py" + (
            f" --episodes {args.episodes}" if args.episodes != 10 else "")
        loop = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators")).loop
        report = {"command": command, "seed": args.seed, "action_mode": "actuators", "loop": loop, "cells": cells,
                  "wall_time_s": round(time.perf_counter() - t0, 1)}
        atomic_write_text(args.json, json.dumps(report, indent=2))
    table = metrics_table(report)
    if args.render_only:
        print(table)
    if page is not None and default_run and page.is_file() and write_block(BLOCK, README_SOURCE, table, page):
        print(f"updated the table in {page}")
    return 0


main = command_main("passivity_metrics.py", _main,
                    "``softpvtol passivity-metrics``: the report under ``layout`` (default: ``./results/``).")
