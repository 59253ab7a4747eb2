"""The sweep behind the distilled cells' settings (benchmarks/STUDIES.md, "Learning from the controllers").

    python benchmarks/distill_sweep.py                   # every setting, one process each (16 processes)
    python benchmarks/distill_sweep.py --workers 2       # two at a time (about 45 CPU-minutes in all)
    python benchmarks/distill_sweep.py --only NAME ...   # these settings again, the others' results kept
    python benchmarks/distill_sweep.py --render-only     # the table again from the JSON

Each setting is one distillation (:func:`softpvtol_gym.baselines.training.distill.distill`) of the integral loop
on ``track_random``, seed 0 unless a setting names another, changed from :data:`BASE` in the settings it names
(the later ones start from the leaderboard's ``small-matched`` students). Per setting: the student's mean error
per window over the evaluation episodes of its last round (8 episodes from seed 3,000,000: not the leaderboard's),
the crashed episodes, the last epoch's loss and the seconds it took. One seed per setting: differences within a
factor of about 1.5 are within the seed-to-seed spread of the leaderboard's distilled cells (docs/baselines.md).
Writes ``benchmarks/distill_sweep.json`` and the table between the ``distill-sweep`` markers of benchmarks/STUDIES.md.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402
from softpvtol_gym.baselines.util.blocks import write_block  # noqa: E402
from softpvtol_gym.baselines.util.environment import temporary_environment  # noqa: E402

OUT = ROOT / "benchmarks" / "distill_sweep.json"
DOC = ROOT / "benchmarks" / "STUDIES.md"
BLOCK, SOURCE = "distill-sweep", "benchmarks/distill_sweep.json"
#: the settings every variant starts from (the committed run results/distill_runs/integral_track_random)
BASE = dict(teacher="integral", task="track_random", tiers=["nominal"], seed=0, net_arch=[256, 256], rounds=4,
            episodes=48, epochs=20, batch_size=1024, learning_rate=1e-3, eval_episodes=8, precision_scale=0.01,
            teacher_integral=False)
#: name -> the settings it changes, in the table's order
VARIANTS = {
    "base": {},
    "precision scale 1e-3": {"precision_scale": 0.001},
    "precision scale 3e-4": {"precision_scale": 0.0003},
    "no precision weights": {"precision_scale": None},
    "40 epochs": {"epochs": 40},
    "40 epochs, learning rate 3e-4": {"epochs": 40, "learning_rate": 3e-4},
    "precision scale 1e-3, 40 epochs": {"precision_scale": 0.001, "epochs": 40},
    "precision scale 1e-3, learning rate 3e-4": {"precision_scale": 0.001, "learning_rate": 3e-4},
    "6 rounds of 32 episodes": {"rounds": 6, "episodes": 32},
    "6 rounds of 32 episodes, precision scale 1e-3": {"rounds": 6, "episodes": 32, "precision_scale": 0.001},
    "3 rounds of 96 episodes": {"rounds": 3, "episodes": 96},
    "batches of 256, 10 epochs": {"batch_size": 256, "epochs": 10},
    "128 x 128, 40 epochs": {"net_arch": [128, 128], "epochs": 40},
    "64 x 64, 60 epochs": {"net_arch": [64, 64], "epochs": 60},
    "4 tiers (nominal, mismatch, wind, noisy), 12 episodes each": {
        "tiers": ["nominal", "mismatch", "wind", "noisy"], "episodes": 12},
    "4 tiers, 12 episodes each, precision scale 1e-3": {
        "tiers": ["nominal", "mismatch", "wind", "noisy"], "episodes": 12, "precision_scale": 0.001},
}
#: the first sweep's settings, from which the leaderboard's distilled cells took theirs
FIRST_SWEEP = tuple(VARIANTS)
#: the leaderboard's small-matched students (64 x 64, 60 epochs, precision scale 1e-3, the teacher's integrals)
SMALL_MATCHED = {"net_arch": [64, 64], "epochs": 60, "precision_scale": 0.001, "teacher_integral": True}
#: each action channel's error divided by its spread (balance_actions), against the same students without, on
#: four seeds; and a few settings around it on seed 0
for _seed in range(4):
    VARIANTS[f"small-matched, seed {_seed}"] = {**SMALL_MATCHED, "seed": _seed}
    VARIANTS[f"small-matched, balanced actions, seed {_seed}"] = {**SMALL_MATCHED, "seed": _seed,
                                                                   "balance_actions": True}
for _seed in range(2):
    VARIANTS[f"small-matched, balanced actions, 256 x 256, 40 epochs, seed {_seed}"] = {
        **SMALL_MATCHED, "net_arch": [256, 256], "epochs": 40, "seed": _seed, "balance_actions": True}
VARIANTS.update({
    "small-matched, balanced actions, 128 x 128": {**SMALL_MATCHED, "net_arch": [128, 128], "balance_actions": True},
    "small-matched, balanced actions, no precision weights": {**SMALL_MATCHED, "precision_scale": None,
                                                              "balance_actions": True},
    "small-matched, balanced actions, 120 epochs": {**SMALL_MATCHED, "epochs": 120, "balance_actions": True},
    "small-matched, balanced actions, 6 rounds": {**SMALL_MATCHED, "rounds": 6, "balance_actions": True},
})
WINDOWS = ("mean_rms_position_error_transient", "mean_rms_position_error_steady", "mean_max_position_error_final_5s")


def run_variant(name: str, scratch: str) -> dict:
    """Distil one variant in ``scratch``; its last round's evaluation, loss and seconds."""
    from softpvtol_gym.baselines.training.distill import DistillConfig, distill

    settings = {**BASE, **VARIANTS[name]}
    config = DistillConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in settings.items()})
    t0 = time.perf_counter()
    record = distill(config, Path(scratch) / name.replace(" ", "_").replace(",", ""))["record"]
    last = record["rounds"][-1]
    return {"settings": VARIANTS[name], "seconds": time.perf_counter() - t0, "loss_last_epoch": last["loss_last_epoch"],
            "evaluation": {tier: row["student"] for tier, row in last["evaluation"].items()},
            "teacher": {tier: row["teacher"] for tier, row in record["rounds"][0]["evaluation"].items()}}


def markdown_table(report: dict) -> str:
    """The table of a report (``distill_sweep.json``): per variant and tier, the last round's mean errors."""
    def cells(s: dict) -> str:
        values = ["crashed" if s.get(k) is None else f"{s[k]:.2e}" for k in WINDOWS]
        return " | ".join(values) + f" | {round(s['crash_rate'] * s['episodes'])}/{s['episodes']}"

    runs = sorted({(v["workers"], v["cpus"]) for v in report["variants"].values()})
    where = "; ".join(f"{w} processes at once on {c} CPUs" for w, c in runs)
    lines = [f"(generated by `python benchmarks/distill_sweep.py`, one seed per setting unless it names one; {where}; "
             "last round's student, mean over its evaluation episodes)", "",
             "| setting (changed from the base) | tier | first quarter [m] | last half [m] | max last 5 s [m] "
             "| crashes | last loss | seconds |", "|---|---|---|---|---|---|---|---|"]
    for name, v in report["variants"].items():
        for tier, s in v["evaluation"].items():
            lines.append(f"| {name} | {tier} | {cells(s)} | {v['loss_last_epoch']:.2e} | {v['seconds']:.0f} |")
    teachers = next(iter(report["variants"].values()))["teacher"]
    for v in report["variants"].values():
        teachers = {**v["teacher"], **teachers}
    for tier, s in teachers.items():
        lines.append(f"| teacher (integral loop) | {tier} | {cells(s)} | | |")
    return "\n".join(lines)


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=len(VARIANTS), help="processes at once (default: one per setting)")
    ap.add_argument("--only", action="append", choices=list(VARIANTS), help="run only these settings (repeatable)")
    ap.add_argument("--out", type=Path, default=OUT, help="default: %(default)s")
    ap.add_argument("--doc", type=Path, default=DOC, help="the page with the table's markers (default: %(default)s)")
    ap.add_argument("--render-only", action="store_true", help="only write the table from --out")
    args = ap.parse_args(argv)
    if args.workers < 1:
        ap.error(f"--workers must be >= 1, got {args.workers}")
    if args.render_only:
        report = json.loads(args.out.read_text())
    else:
        names = args.only or list(VARIANTS)
        # one numba thread per worker unless the user chose; set for the workers' start only
        worker_env = {} if "NUMBA_NUM_THREADS" in os.environ else {"NUMBA_NUM_THREADS": "1"}
        with tempfile.TemporaryDirectory() as scratch:
            with temporary_environment(worker_env):
                pool = multiprocessing.get_context("spawn").Pool(min(args.workers, len(names)))
            with pool:
                results = pool.starmap(run_variant, [(n, scratch) for n in names])
        run = {"commit": _commit(), "workers": min(args.workers, len(names)), "cpus": os.cpu_count()}
        fresh = {n: {**r, **run} for n, r in zip(names, results, strict=True)}
        # with --only, the other settings' results stay, each with the run that made it
        kept = json.loads(args.out.read_text())["variants"] if args.only and args.out.is_file() else {}
        report = {"base": BASE, "variants": {n: fresh.get(n, kept.get(n)) for n in VARIANTS if n in fresh or n in kept}}
        atomic_write_text(args.out, json.dumps(report, indent=1))
    if write_block(BLOCK, SOURCE, markdown_table(report), args.doc):
        print(f"wrote the table into {args.doc}")
    print(markdown_table(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
