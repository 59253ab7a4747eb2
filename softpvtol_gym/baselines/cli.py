"""``softpvtol``: the console command of the baselines (``[project.scripts]``), one subcommand per job.

    softpvtol --help                 # the subcommands
    softpvtol SUBCOMMAND --help      # a subcommand's options (the same as its checkout script's)
    softpvtol evaluate --policy passivity --episodes 10 --json results/passivity.json
    python -m softpvtol_gym.baselines ...   # the same

Every subcommand writes where its options say, by default under the current directory (``./runs/`` for
training runs, ``./results/`` for everything else), never into the installed package, and touches no
README or docs page. A source checkout's scripts (``python train.py``, ``python baselines/<script>.py``) run
the same commands with the checkout's paths.

A subcommand's module is imported only after the packages it needs are found
(:func:`softpvtol_gym.baselines.util.extras.require`), so a missing extra is one line with exit code 2;
bad input is one line with exit code 2 too; an I/O error (disk full, read-only) one line naming the path,
exit 74; Ctrl-C exit 130, SIGTERM 143 (:mod:`softpvtol_gym.baselines.util.args`, docs/baselines.md).
"""

from __future__ import annotations

import importlib
import os
import sys

from softpvtol_gym.baselines.errors import EXIT_SIGINT, EXIT_SIGTERM
from softpvtol_gym.baselines.util.extras import require
from softpvtol_gym.baselines.util.paths import Layout

PROG = "softpvtol"


#: subcommand -> (module under softpvtol_gym.baselines.commands, the checkout script's name, summary)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "train": ("train", "train.py", "train an agent (PPO/SAC) and compare it with the passivity controller"),
    "evaluate": ("evaluate", "evaluate.py", "evaluate a policy (passivity or a checkpoint) on a task and tier"),
    "distill": ("distill", "distill.py", "learn a student network from a controller (behaviour cloning + DAgger)"),
    "export": ("export", "export.py", "convert checkpoints between the safe format and SB3's files"),
    "run-jobs": ("run_jobs", "run_jobs.py", "run the leaderboard's job list (local processes or Ray)"),
    "leaderboard": ("leaderboard", "leaderboard.py", "build the leaderboard (statistics, JSON, Markdown, chart)"),
    "score": ("score", "score.py", "score your own policy (MODULE:FACTORY) and rank it among the leaderboard's"),
    "ablation": ("ablation", "ablation.py", "the learned controller's ablation table (recipes x windows)"),
    "tune": ("tune", "tune.py", "search hyperparameters with Ray Tune (the 'distributed' extra)"),
    "figures": ("figures", "tracking_figures.py", "tracking plots, learning curves and a GIF of a learned policy"),
    "render-gif": ("render_gif", "render_gif.py", "render an episode of a policy to an animated GIF"),
    "model-figures": ("model_figures", "model_figures.py", "integration error of the paper's loop (RK4 steps)"),
    "reproduce-paper": ("reproduce_paper", "reproduce_paper.py", "reproduce the paper's simulation section"),
    "passivity-metrics": ("passivity_metrics", "passivity_metrics.py", "the passivity policy on every task x tier"),
    "results": ("results", "results.py", "pack the results into their committed archives, or unpack them"),
}


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"usage: {PROG} SUBCOMMAND [options]   ({PROG} SUBCOMMAND --help for its options)", "",
             "Soft-PVTOL baselines: training, evaluation, the leaderboard and the figures. Outputs go under the",
             "current directory by default (./runs/, ./results/).", "", "subcommands:"]
    lines += [f"  {name:<{width}}  {summary}" for name, (_, _, summary) in COMMANDS.items()]
    return "\n".join(lines) + "\n"


def run_command(name: str, argv: list[str], layout: Layout | None = None, prog: str | None = None) -> int:
    """Run subcommand ``name`` with ``argv`` (its options) and ``layout`` (default: the current directory's)."""
    module, script, _ = COMMANDS[name]
    prog = prog or f"{PROG} {name}"
    require(script, prog=prog)  # before the module is imported: a missing extra is one line, not a traceback
    command = importlib.import_module(f"softpvtol_gym.baselines.commands.{module}")
    return command.main(argv, layout=layout or Layout(), prog=prog)


def main(argv: list[str] | None = None) -> int:
    """The console command: ``softpvtol SUBCOMMAND [options]``; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        sys.stderr.write(usage())
        return 2
    if argv[0] in ("-h", "--help"):
        sys.stdout.write(usage())
        return 0
    name = argv[0]
    if name not in COMMANDS:
        close = [c for c in COMMANDS if c.startswith(name[:3])]
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        sys.stderr.write(f"{PROG}: error: unknown subcommand {name!r}{hint} (see {PROG} --help)\n")
        return 2
    try:
        return run_command(name, argv[1:])
    except SystemExit as exc:
        leave_now_after_a_ray_interrupt(exc.code)
        raise


def leave_now_after_a_ray_interrupt(code) -> None:
    """After Ctrl-C or SIGTERM (exit 130 / 143) in a process that used Ray, end the process at once.

    The command has already shut Ray down (:func:`~softpvtol_gym.baselines.leaderboard.ray_executor.start_ray`),
    removed its temporary folder and printed its one line; Ray's core worker can still abort (SIGABRT) while
    the interpreter shuts down after a signal, which would replace the documented exit code (seen once in CI's
    run of test_run_jobs_on_ray_terminated_leaves_no_ray_process_or_temp_folder). For the console process only:
    ``main`` and the checkout scripts call it, the library never does."""
    if code in (EXIT_SIGINT, EXIT_SIGTERM) and "ray" in sys.modules:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
