"""Score the learned controller's ablation and render its table.

    softpvtol ablation --spec ablation.yml --root results/ablation_runs

In a source checkout, ``python baselines/ablation.py`` reads ``baselines/ablation.yml`` and its runs under
``results/ablation_runs`` (made by ``python baselines/run_jobs.py --spec baselines/ablation.yml --root
results/ablation_runs``), takes its first row from the leaderboard's runs, and writes
``results/ablation.json`` and the table in docs/baselines.md ("Ablation"). ``--from-json`` only
re-renders the table. Exit codes as the other commands: 0 done, 2 bad input (a missing run names itself).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from softpvtol_gym.baselines.leaderboard.ablation import build, render_markdown
from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE
from softpvtol_gym.baselines.leaderboard.stats import first_non_finite
from softpvtol_gym.baselines.util.args import Parser, command_main
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.blocks import write_block
from softpvtol_gym.baselines.util.paths import Layout, relative_to_root
from softpvtol_gym.baselines.util.safe_load import loads_json

SOURCE = "results/ablation.json"
BLOCK = ("ablation.py table", SOURCE)


def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", type=Path, default=layout.root / "baselines" / "ablation.yml" if layout.readme
                    else Path("ablation.yml"), help="the ablation spec (default: %(default)s)")
    ap.add_argument("--root", type=Path, default=layout.results / "ablation_runs", help="default: %(default)s")
    ap.add_argument("--leaderboard-root", type=Path, default=layout.runs,
                    help="the leaderboard's runs, for the reference row (default: %(default)s)")
    ap.add_argument("--json", type=Path, default=layout.results / "ablation.json", help="default: %(default)s")
    ap.add_argument("--from-json", action="store_true", help="only re-render the table from the JSON")
    args = ap.parse_args(argv)
    if args.from_json:
        if not args.json.is_file():
            ap.error(f"--json {args.json} is not a file (make it without --from-json first)")
        try:
            data = loads_json(args.json.read_text(), str(args.json))
            render_markdown(data)
        except (ValueError, KeyError, TypeError) as exc:
            ap.error(f"--json {args.json} is not an ablation JSON ({type(exc).__name__}: {exc}); make it again "
                     f"without --from-json")
        non_finite = first_non_finite(data)
        if non_finite is not None:  # the writer never writes one (allow_nan=False): the file was edited or damaged
            ap.error(f"--json {args.json}: {non_finite} is not a finite number (NaN or infinity), expected a finite "
                     f"one; make the JSON again without --from-json (nothing was written)")
    else:
        for path, what in ((args.root, "--root"), (args.leaderboard_root, "--leaderboard-root")):
            if not path.is_dir():
                ap.error(f"{what} {path} is not a directory")
        data = build(args.spec, args.root, SPEC_FILE, args.leaderboard_root)
        data["spec"] = relative_to_root(args.spec, layout.root)  # as eval.json's checkpoints: no machine's path
        atomic_write_text(args.json, json.dumps(data, indent=1, allow_nan=False))
    table = render_markdown(data)
    page = layout.doc("baselines.md")
    wrote_table = page is not None and write_block(*BLOCK, table, page)
    written = ([] if args.from_json else [str(args.json)]) + ([f"the table in {page}"] if wrote_table else [])
    if not wrote_table:
        print(table)
    if written:
        print(f"wrote {' and '.join(written)}")
    return 0


main = command_main("ablation.py", _main, "``softpvtol ablation``: the ablation table of the learned controller.")
