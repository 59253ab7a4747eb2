"""Build the leaderboard from the job results: statistics (rliable), JSON, a Markdown page and a chart.

    softpvtol leaderboard              # ./results/leaderboard_runs -> ./results/leaderboard.{json,md,png}
    softpvtol leaderboard --from-json  # only re-render the page and the chart from the JSON

In a source checkout, ``python baselines/leaderboard.py`` writes ``results/leaderboard.json``, the
page ``docs/leaderboard.md`` and the chart ``results/leaderboard.png``, and refreshes the README's
summary block.

Inputs: the ``eval.json`` of every job of the spec (default: the package's ``leaderboard.yml``) under
``--root`` (``softpvtol run-jobs`` makes them).

Statistics (rliable, Agarwal et al. 2021): for each (task, evaluation tier) and each entry (a policy;
for PPO an action mode and the tier it was trained on), the scores form a matrix (runs x episodes):
runs are the PPO training seeds (one row for the deterministic passivity controllers), episodes the
shared, seeded evaluation episodes. Point estimates are the IQM (interquartile mean) of the RMS
position error and of the return, and the mean crash rate; 95 % CIs come from rliable's stratified
bootstrap over runs *and* episodes (``task_bootstrap=True``), so they include both the seed-to-seed
variation of training and the finite evaluation set. The probability of improvement P(X < Y) of an
entry over the best passivity controller is rliable's (Mann-Whitney over runs, averaged over
episodes), on the RMS position error; its CI resamples runs only (rliable's independent-samples
bootstrap for pairs does not support resampling episodes), so for the passivity-vs-passivity row it
is a point. The bootstrap is seeded: the JSON, and
therefore docs/leaderboard.md, are reproducible.

Per row, the leaderboard holds the IQM and CI of each time window (first quarter, last half, max over the last
5 s; a crashed window counts as worse than any value: "crash" where it reaches the IQM or a CI bound) and the
median compute per step; a deterministic task and tier (an entry there has identical episodes) counts each run
once, so its CIs come from the training seeds only. The headline compares, per (task, tier, window), the
strongest learned entry with the strongest model-based controller (docs/baselines.md, "The leaderboard"). Results
recorded before the windowed metrics are listed as stale and left out: ``softpvtol run-jobs --rescore`` first.

The output paths are checked, and the spec, every job result (required keys and types, finite numbers: a NaN in an
``eval.json`` is refused naming the file) or the JSON validated, before any work; then every output (JSON, Markdown,
PNG, the README block, and the distilled cells' tables in ``docs/baselines.md``) is rendered in memory and
written together: each to a temporary file first, renamed over the targets only once all are written, so a failure
(bad input, a full disk) changes none of them. Exit codes: 0 done, 2 bad input (one line, nothing written), 74 an
output that cannot be written (one line naming it; nothing changed), 130 / 143 interrupted (nothing changed).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

from softpvtol_gym.baselines.leaderboard.distilled import ABLATION_BLOCK, ROUNDS_BLOCK, ablation_table, rounds_table
from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE, load_jobs
from softpvtol_gym.baselines.leaderboard.render import SUMMARY_BLOCK, chart_png, render_markdown, summary_markdown
from softpvtol_gym.baselines.leaderboard.spec import INFERENCE
from softpvtol_gym.baselines.leaderboard.stats import build, learned_name, read_data, validate_data
from softpvtol_gym.baselines.leaderboard.summary import SUMMARY_FILE, summary_bytes
from softpvtol_gym.baselines.training.distill import DISTILL_FILE
from softpvtol_gym.baselines.util.args import Parser, check_output_file, command_main, refuse_overwrite
from softpvtol_gym.baselines.util.atomic import atomic_write_all
from softpvtol_gym.baselines.util.blocks import markers
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.baselines.util.safe_load import loads_json


def _check_output(path: Path, option: str) -> None:
    check_output_file(path, force=True, option=option)


def _replace_block(text: str, name: str, source: str, table: str) -> str:
    """``text`` with the block ``name`` replaced by ``table`` (as :func:`write_block`; unchanged without it)."""
    start, end = markers(name, source)
    if start not in text or end not in text:
        return text
    a, b = text.index(start) + len(start), text.index(end)
    return text[:a] + "\n" + table.strip() + "\n" + text[b:]


def _with_block(name: str, source: str, table: str, path: Path) -> bytes | None:
    """``path``'s text with the block ``name`` replaced by ``table`` (as :func:`write_block`), or None if it has
    no such block."""
    text = path.read_text(encoding="utf-8")
    start, end = markers(name, source)
    if start not in text or end not in text:
        return None
    return _replace_block(text, name, source, table).encode("utf-8")


def finetune_reward_runs(folder: Path) -> dict[str, list[dict]]:
    """The periodic evaluations of the fine-tuning runs with and without the precision reward under ``folder``
    (``<name>/evaluations.json``)."""
    out = {}
    for path in sorted(Path(folder).glob("*/evaluations.json")):
        out[path.parent.name] = loads_json(path.read_text(), str(path))
    return out


def distilled_records(root: Path, spec: Path = SPEC_FILE) -> dict[str, list[dict]]:
    """The ``distill.json`` records of the spec's distilled jobs under ``root``: entry name -> the seeds' records
    (jobs without one left out)."""
    out: dict[str, list[dict]] = {}
    for job in load_jobs(spec):
        path = job.folder(root) / DISTILL_FILE
        if job.policy == "distilled" and path.is_file():
            out.setdefault(learned_name(dataclasses.asdict(job)), []).append(loads_json(path.read_text(), str(path)))
    return out


def _main(argv, layout: Layout, prog: str) -> int:
    page = layout.doc("leaderboard.md") or layout.results / "leaderboard.md"
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--from-json", action="store_true", help="only re-render from the committed JSON")
    ap.add_argument("--json", type=Path, default=layout.results / "leaderboard.json", help="default: %(default)s")
    ap.add_argument("--markdown", type=Path, default=page, help="the leaderboard page (default: %(default)s)")
    ap.add_argument("--chart", type=Path, default=layout.results / "leaderboard.png", help="default: %(default)s")
    ap.add_argument("--root", type=Path, default=layout.runs, help="the jobs' run directories (default: %(default)s)")
    ap.add_argument("--spec", type=Path, default=SPEC_FILE,
                    help="the job list (default: the package's leaderboard.yml)")
    ap.add_argument("--inference", choices=INFERENCE, default=None,
                    help="the forward pass the learned results were scored with (default: the spec's, lean); results "
                         "scored otherwise are listed as stale")
    ap.add_argument("--force", action="store_true",
                    help="let other inputs (--root, --spec, or --json with --from-json) overwrite the default outputs")
    args = ap.parse_args(argv)
    refuse_overwrite(ap, args, ("root", "spec") + (("json",) if args.from_json else ()),
                     [(args.markdown, page, "--markdown"), (args.chart, ap.get_default("chart"), "--chart")]
                     + ([] if args.from_json else [(args.json, ap.get_default("json"), "--json")]))
    for path, option in ((args.markdown, "--markdown"), (args.chart, "--chart")) + (
            () if args.from_json else ((args.json, "--json"),)):
        _check_output(path, option)
    if args.from_json:
        data = read_data(args.json)
    else:
        if not args.root.is_dir():
            ap.error(f"--root {args.root} is not a directory")
        data = build(args.root, args.spec, base=layout.root, inference=args.inference)
        data = validate_data(json.loads(json.dumps(data)), "built from " + str(args.root))  # what is written renders
    # everything rendered in memory first, then written all together (nothing changes if any part fails)
    outputs = {}
    if not args.from_json:
        outputs[args.json] = json.dumps(data, indent=1, allow_nan=False).encode("utf-8")
    chart_link = os.path.relpath(args.chart.resolve(), args.markdown.resolve().parent)
    outputs[args.markdown] = render_markdown(data, chart=chart_link).encode("utf-8")
    outputs[args.chart] = chart_png(data)
    if args.markdown.resolve() == page.resolve():  # the committed page: the package's summary too
        outputs[SUMMARY_FILE] = summary_bytes(data)
    if layout.readme is not None and args.markdown.resolve() == page.resolve():  # the committed page: the README too
        link = os.path.relpath(page.resolve(), layout.readme.resolve().parent)
        readme = _with_block(*SUMMARY_BLOCK, summary_markdown(data, link), layout.readme)
        if readme is not None:
            outputs[layout.readme] = readme
    students = distilled_records(args.root, args.spec) if args.root.is_dir() else {}
    guide = layout.doc("baselines.md")
    if students and guide is not None and guide.is_file() and args.markdown.resolve() == page.resolve():
        text = guide.read_text(encoding="utf-8")  # docs/baselines.md: the students' rounds and the ablation
        reward_runs = finetune_reward_runs(layout.results / "distill_runs" / "finetune_reward")
        for block, table in ((ROUNDS_BLOCK, rounds_table(students)),
                             (ABLATION_BLOCK, ablation_table(data["aggregates"], students, reward_runs))):
            text = _replace_block(text, *block, table)
        outputs[guide] = text.encode("utf-8")
    atomic_write_all(outputs)
    print(f"wrote {args.markdown} and {args.chart}" + ("" if args.from_json else f" from {args.json}"))
    return 0


main = command_main("leaderboard.py", _main,
                    "``softpvtol leaderboard``: outputs under ``layout`` (default: the current directory's "
                    "``results/``).")
