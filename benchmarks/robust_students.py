"""The robust students' probe (benchmarks/STUDIES.md, "Robust students: the field's recipe, a first probe").

    python benchmarks/robust_students.py                  # every variant, one process each
    python benchmarks/robust_students.py --only NAME ...  # these variants again, the others' results kept
    python benchmarks/robust_students.py --render-only    # the table again from the JSON
    python benchmarks/robust_students.py --crashes NAME   # where the kept student of NAME crashes on hover
    python benchmarks/robust_students.py --teacher-recovery  # the MPC from turned starts, into the JSON and table

Each variant is one distillation (:func:`softpvtol_gym.baselines.training.distill.distill`) of the MPC, seed 0,
changed from :data:`BASE` in the settings it names: the teacher's DAgger on a mixture of the randomised tiers and
of hover and track_random, a quarter of the episodes started wide, the teacher's share of the DAgger rounds going
to 0 (0.5, 0.2, 0). Per variant and (task, tier): the student's mean error per window over the evaluation episodes
of its last round (8 episodes from seed 3,000,000 on: the tuning range, neither the leaderboard's test nor its
selection episodes), the crashed episodes, and the teacher's on the same episodes. One seed per variant. The
students are kept under ``runs/robust_students/<variant>`` (``--keep DIR`` to choose) for evaluation and
fine-tuning. Writes ``benchmarks/robust_students.json`` and the table between the ``robust-students`` markers of
benchmarks/STUDIES.md.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.distill_sweep import WINDOWS, _commit  # noqa: E402
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402
from softpvtol_gym.baselines.util.blocks import write_block  # noqa: E402
from softpvtol_gym.baselines.util.environment import temporary_environment  # noqa: E402

OUT = ROOT / "benchmarks" / "robust_students.json"
DOC = ROOT / "benchmarks" / "STUDIES.md"
KEEP = ROOT / "runs" / "robust_students"
BLOCK, SOURCE = "robust-students", "benchmarks/robust_students.json"
#: the tiers of the mixture (every randomised tier of the leaderboard, and nominal)
MIXTURE = ["nominal", "noisy", "hard", "mismatch", "model_gap"]
#: the settings every variant starts from
BASE = dict(teacher="mpc", task="track_random", also_tasks=["hover"], tiers=MIXTURE, seed=0, net_arch=[256, 256],
            rounds=4, episodes=8, epochs=20, batch_size=1024, learning_rate=1e-3, eval_episodes=8,
            wide_fraction=0.25, teacher_shares=[0.5, 0.2, 0.0], history=4)
#: recovery data: a quarter of the episodes start turned and spinning, a fifth round, the teacher's share held
TURNED = {"privileged": True, "attitude_fraction": 0.25, "rounds": 5, "teacher_shares": [0.5, 0.5, 0.2, 0.0]}
#: the student as a residual on the integral loop's command clipped to the actuator box
SATURATED_RESIDUAL = {"residual_on": "integral", "residual_base": "saturated"}
#: name -> the settings it changes, in the table's order
VARIANTS = {
    "tier mixture, history 4": {},
    "tier mixture, history 4, privileged": {"privileged": True},
    "tier mixture, history 20 (0.2 s), privileged": {"privileged": True, "history": 20},
    "tier mixture, history 4, privileged, residual on the integral loop": {"privileged": True,
                                                                           "residual_on": "integral"},
    "tier mixture, history 4, privileged, residual on the saturated integral loop": {
        "privileged": True, **SATURATED_RESIDUAL},
    "tier mixture, history 20 (0.2 s), privileged, residual on the saturated integral loop": {
        "privileged": True, "history": 20, **SATURATED_RESIDUAL},
    "tier mixture, history 4, privileged, turned starts, 5 rounds": TURNED,
    "tier mixture, history 4, privileged, turned starts, 5 rounds, residual on the saturated integral loop": {
        **TURNED, **SATURATED_RESIDUAL},
    # a bounded residual: the student may move the saturated loop's command by at most a quarter (a half) of the
    # actuator half-ranges, so that the loop, which crashes nowhere, bounds what the student can spoil
    "tier mixture, history 4, privileged, turned starts, 5 rounds, bounded residual (0.25) on the saturated "
    "integral loop": {**TURNED, **SATURATED_RESIDUAL, "residual_scale": 0.25},
    "tier mixture, history 4, privileged, turned starts, 5 rounds, bounded residual (0.5) on the saturated "
    "integral loop": {**TURNED, **SATURATED_RESIDUAL, "residual_scale": 0.5},
    # the bounded residual (0.25) with memory long enough to see a parameter error act: 0.1 s and 0.2 s of history
    "tier mixture, history 10 (0.1 s), privileged, turned starts, 5 rounds, bounded residual (0.25) on the "
    "saturated integral loop": {**TURNED, **SATURATED_RESIDUAL, "residual_scale": 0.25, "history": 10},
    "tier mixture, history 20 (0.2 s), privileged, turned starts, 5 rounds, bounded residual (0.25) on the "
    "saturated integral loop": {**TURNED, **SATURATED_RESIDUAL, "residual_scale": 0.25, "history": 20},
}


def run_variant(name: str, keep: str, seed: int = 0) -> dict:
    """Distil one variant with run seed ``seed`` into ``keep``/<variant folder>; its last round's evaluation and
    seconds, the teacher's."""
    import torch

    from softpvtol_gym.baselines.training.distill import distill

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    record = distill(variant_config(name, seed), Path(keep) / slug(name, seed), resume=True)["record"]
    return variant_result(name, record, time.perf_counter() - t0)


def variant_config(name: str, seed: int = 0):
    """The :class:`~softpvtol_gym.baselines.training.distill.DistillConfig` of variant ``name`` at run seed ``seed``."""
    from softpvtol_gym.baselines.training.distill import DistillConfig

    settings = {**BASE, **VARIANTS[name], "seed": seed}
    return DistillConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in settings.items()})


def variant_result(name: str, record: dict, seconds: float) -> dict:
    """What the JSON keeps of a variant's distillation record (``distill.json``): its last round's evaluation, the
    teacher's (round 0), the data and the seconds."""
    last = record["rounds"][-1]
    return {"settings": VARIANTS[name], "seconds": seconds, "loss_last_epoch": last["loss_last_epoch"],
            "samples": last["aggregate"], "labels_at_clip": last.get("labels_at_clip"),
            "evaluation": {cell: row["student"] for cell, row in last["evaluation"].items()},
            "teacher": {cell: row["teacher"] for cell, row in record["rounds"][0]["evaluation"].items()}}


#: the variant that the leaderboard's ``distilled mpc robust`` cell runs at seeds 0-4, and that cell's run folder
LEADERBOARD_VARIANT = "tier mixture, history 4, privileged, turned starts, 5 rounds"
LEADERBOARD_CELL = ROOT / "results" / "leaderboard_runs" / "distilled-mpc-robust_track_random_nominal"
#: the variant of the ``distilled mpc robust-bounded`` cell
BOUNDED_VARIANT = ("tier mixture, history 4, privileged, turned starts, 5 rounds, bounded residual (0.25) on the "
                   "saturated integral loop")
#: every variant that a leaderboard cell runs -> that cell's run folder
LEADERBOARD_CELLS = {LEADERBOARD_VARIANT: LEADERBOARD_CELL,
                     BOUNDED_VARIANT: ROOT / "results" / "leaderboard_runs"
                     / "distilled-mpc-robust-bounded_track_random_nominal"}


def leaderboard_seeds(cell: Path = LEADERBOARD_CELL, variant: str = LEADERBOARD_VARIANT) -> dict:
    """Seed -> result of ``variant`` from the leaderboard cell's runs of seeds 1 and up (their ``distill.json``;
    ``python baselines/results.py unpack`` puts them there), each checked to have the variant's settings at its
    seed."""
    import dataclasses

    from softpvtol_gym.baselines.training.distill_config import EARLIER_DEFAULTS

    out = {}
    for seed in sorted(int(f.name.removeprefix("seed_")) for f in cell.glob("seed_*") if not f.name.endswith(".run")):
        folder = cell / f"seed_{seed}"
        if seed == 0:
            continue
        record = json.loads((folder / "distill.json").read_text())
        expected = json.loads(json.dumps(dataclasses.asdict(variant_config(variant, seed))))
        if {k: record["config"].get(k, EARLIER_DEFAULTS.get(k)) for k in expected} != expected:
            raise SystemExit(f"{folder}: its settings are not those of the variant {variant!r} at seed {seed}")
        out[str(seed)] = variant_result(variant, record, record["seconds"])
    if not out:
        raise SystemExit(f"no runs of seed 1 and up under {cell}: run `python baselines/results.py unpack` first")
    return out


def merge_seeds(earlier: dict, taken: dict) -> tuple[dict, list[str]]:
    """``earlier`` (seed -> result of a variant) with the seeds of the leaderboard cell's ``taken`` that it lacks
    (a seed in both keeps its earlier run); and the seeds in both whose students differ (their evaluations)."""
    both = sorted(set(earlier) & set(taken), key=int)
    differ = [seed for seed in both if any(earlier[seed][k] != taken[seed][k] for k in ("evaluation", "teacher"))]
    return {**taken, **earlier}, differ


def slug(name: str, seed: int = 0) -> str:
    """A variant's folder name (seed 0's without a suffix)."""
    return "".join(c if c.isalnum() else "_" for c in name).strip("_") + (f"_seed_{seed}" if seed else "")


def markdown_table(report: dict) -> str:
    """The table of a report (``robust_students.json``): per (task, tier), the teacher's and each variant's
    last-round mean errors and crashes."""
    def cells(s: dict) -> str:
        values = ["crashed" if s.get(k) is None else f"{s[k]:.2e}" for k in WINDOWS]
        return " | ".join(values) + f" | {round(s['crash_rate'] * s['episodes'])}/{s['episodes']}"

    runs = sorted({(v["workers"], v["cpus"]) for v in report["variants"].values()})
    where = "; ".join(f"{w} processes at once on {c} CPUs" for w, c in runs)
    lines = [f"(generated by `python benchmarks/robust_students.py`, seed 0; {where}; last round's student, mean over "
             "its 8 evaluation episodes per task and tier)", "",
             "| task and tier | policy | first quarter [m] | last half [m] | max last 5 s [m] | crashes |",
             "|---|---|---|---|---|---|"]
    first = next(iter(report["variants"].values()))
    for cell in first["evaluation"]:
        name = cell if " " in cell else f"{report['base']['task']} {cell}"
        teacher = next((v["teacher"][cell] for v in report["variants"].values() if cell in v["teacher"]), None)
        if teacher is not None:
            lines.append(f"| {name} | teacher (MPC) | {cells(teacher)} |")
        for variant, v in report["variants"].items():
            if cell in v["evaluation"]:
                lines.append(f"| {name} | {variant} | {cells(v['evaluation'][cell])} |")
    lines += ["", "| variant | samples (all rounds) | last loss | residual labels at the clip, last round (T_l, T_r, "
              "tau_l, tau_r) | seconds |", "|---|---|---|---|---|"]
    for variant, v in report["variants"].items():
        shares = v.get("labels_at_clip")
        clip = "" if shares is None else ", ".join(f"{100 * x:.0f} %" for x in shares)
        lines.append(f"| {variant} | {v['samples']:,} | {v['loss_last_epoch']:.2e} | {clip} | {v['seconds']:.0f} |")
    if "teacher_recovery" in report:
        lines.append(recovery_table(report["teacher_recovery"]))
    if "seeds" in report:
        lines.append(seeds_table(report))
    return "\n".join(lines)


#: the cells of the seeds table: where the students crash and the MPC hardly does
CRASH_CELLS = ("noisy", "hard", "model_gap", "hover noisy", "hover hard", "hover model_gap")


def _pairs(runs: list[dict], cells: list[str]) -> list[dict]:
    """The student's and the teacher's summaries of each run in each of ``cells``."""
    return [{k: v[k][c] for k in ("evaluation", "teacher")} for v in runs for c in cells]


def seeds_table(report: dict) -> str:
    """Per variant with further seeds and per seed: the crashes of the last round's student and the teacher's on the
    evaluation episodes of that seed, in :data:`CRASH_CELLS` and over every task and tier; then their sums."""
    def crashes(summaries: list[dict]) -> str:
        return "{} ({})".format(*(sum(round(s[k]["crash_rate"] * s[k]["episodes"]) for s in summaries)
                                  for k in ("evaluation", "teacher")))

    n = report["base"]["eval_episodes"]
    head = " | ".join(c if " " in c else f"track_random {c}" for c in CRASH_CELLS)
    lines = ["", f"Over seeds (`--seed S`; the leaderboard cell's seeds with `--leaderboard-seeds`): crashes of the "
             f"last round's student (the teacher's in brackets) in {n} evaluation episodes per task and tier and seed, "
             "from seed 3,000,000 + 1,000 S:", "",
             f"| variant | seed | {head} | all cells |", "|---|---|" + "---|" * (len(CRASH_CELLS) + 1)]
    for name, by_seed in report["seeds"].items():
        runs = sorted({"0": report["variants"][name], **by_seed}.items(), key=lambda kv: int(kv[0]))
        rows = [(seed, [v]) for seed, v in runs] + [(f"all {len(runs)}", [v for _, v in runs])]
        for seed, vs in rows:
            per_cell = [crashes(_pairs(vs, [c])) for c in CRASH_CELLS]
            every = _pairs(vs, list(vs[0]["evaluation"]))
            lines.append(f"| {name} | {seed} | {' | '.join(per_cell)} | {crashes(every)} of {len(every) * n} |")
    return "\n".join(lines)


def print_crashes(name: str, keep: Path, tiers=("noisy", "hard", "model_gap")) -> None:
    """Each crash of variant ``name``'s kept student on its hover evaluation episodes: the tier, the episode, the
    time, the env's termination reason and the state the step started from."""
    import numpy as np
    import torch

    from softpvtol_gym import SoftPVTOLVectorEnv
    from softpvtol_gym.baselines.training.distill import DISTILL_EVAL_SEED
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    torch.set_num_threads(1)
    policy, run = LearnedPolicy.load(keep / slug(name))
    n = BASE["eval_episodes"]
    for tier in tiers:
        env = SoftPVTOLVectorEnv(num_envs=n, action_mode=run.action_mode, task="hover", tier=tier,
                                 controller_loop=run.controller_loop, **run.env_options)
        obs, _ = env.reset(seed=DISTILL_EVAL_SEED + 1_000 * BASE["seed"])
        start, done = np.ones(n, bool), np.zeros(n, bool)
        while not done.all():
            action, _ = policy.predict(obs, episode_start=start, deterministic=True)
            start[:] = False
            q = env.state[0].copy()
            obs, _, term, trunc, info = env.step(action)
            for i in np.flatnonzero(term & ~done):
                print(f"hover {tier} episode {i}: t = {info['time'][i]:.2f} s, {info['termination_reason'][i]}, "
                      f"q = {np.round(q[i], 2).tolist()}")
            done |= term | trunc


#: the teacher's episodes from turned starts (the env's start_distribution="attitude") per task and tier: seeds
#: 3,100,000 + i (the tuning range, apart from the evaluation episodes)
RECOVERY_EPISODES, RECOVERY_SEED = 8, 3_100_000


def teacher_recovery() -> dict:
    """Per task and tier of the mixture: the MPC's crashes and last-half error from turned starts."""
    import torch

    from softpvtol_gym.baselines.evaluation import run_episodes, summarize
    from softpvtol_gym.baselines.training.distill import DistillConfig
    from softpvtol_gym.baselines.training.teachers import teacher_policy

    torch.set_num_threads(1)
    options = {**DistillConfig(teacher=BASE["teacher"], tiers=("noisy",)).env_options, "start_distribution": "attitude"}
    out = {}
    for task in [BASE["task"], *BASE["also_tasks"]]:
        teacher = teacher_policy(BASE["teacher"], task, options)
        for tier in MIXTURE:
            s = summarize(run_episodes(teacher, "actuators", task, tier, RECOVERY_EPISODES, RECOVERY_SEED,
                                       env_kwargs=options))
            out[f"{task} {tier}"] = {"crashes": round(s["crash_rate"] * s["episodes"]), "episodes": s["episodes"],
                                     "last_half": s.get("mean_rms_position_error_steady")}
    return out


def recovery_table(recovery: dict) -> str:
    """The teacher's recoveries from turned starts, one row per task and tier."""
    lines = ["", f"The teacher (MPC) from turned starts (`start_distribution=\"attitude\"`, {RECOVERY_EPISODES} "
             f"episodes per task and tier from seed {RECOVERY_SEED:,}; `--teacher-recovery`):", "",
             "| task and tier | crashes | last half [m] |", "|---|---|---|"]
    for cell, r in recovery.items():
        half = "crashed" if r["last_half"] is None else f"{r['last_half']:.2e}"
        lines.append(f"| {cell} | {r['crashes']}/{r['episodes']} | {half} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=len(VARIANTS), help="processes at once (default: one per variant)")
    ap.add_argument("--only", action="append", choices=list(VARIANTS), help="run only these variants (repeatable)")
    ap.add_argument("--keep", type=Path, default=KEEP, help="where the students are kept (default: %(default)s)")
    ap.add_argument("--out", type=Path, default=OUT, help="default: %(default)s")
    ap.add_argument("--doc", type=Path, default=DOC, help="the page with the table's markers (default: %(default)s)")
    ap.add_argument("--render-only", action="store_true", help="only write the table from --out")
    ap.add_argument("--crashes", choices=list(VARIANTS), metavar="VARIANT",
                    help="print where the kept student of VARIANT crashes on hover's noisy, hard and model_gap tiers")
    ap.add_argument("--seed", type=int, default=0,
                    help="the run seed of the variants (default 0: the table's; another seed goes to the seeds table)")
    ap.add_argument("--leaderboard-seeds", action="store_true",
                    help="take the seeds 1-4 of the variants that leaderboard cells run from those cells' runs into "
                         "the seeds table (run `python baselines/results.py unpack` first)")
    ap.add_argument("--teacher-recovery", action="store_true",
                    help="run the teacher from turned starts on every task and tier, keep it in --out, write the table")
    args = ap.parse_args(argv)
    if args.teacher_recovery:
        report = json.loads(args.out.read_text())
        report["teacher_recovery"] = teacher_recovery()
        atomic_write_text(args.out, json.dumps(report, indent=1))
        args.render_only = True
    if args.leaderboard_seeds:
        report = json.loads(args.out.read_text())
        seeds = report.setdefault("seeds", {})
        for variant, cell in LEADERBOARD_CELLS.items():
            seeds[variant], differ = merge_seeds(seeds.get(variant, {}), leaderboard_seeds(cell, variant))
            for seed in differ:
                print(f"seed {seed} of {variant!r}: the leaderboard cell's run gave other students than the probe's "
                      "(the probe's is kept)")
        atomic_write_text(args.out, json.dumps(report, indent=1))
        args.render_only = True
    if args.crashes:
        print_crashes(args.crashes, args.keep)
        return 0
    if args.workers < 1:
        ap.error(f"--workers must be >= 1, got {args.workers}")
    if args.render_only:
        report = json.loads(args.out.read_text())
    else:
        names = args.only or list(VARIANTS)
        worker_env = {} if "NUMBA_NUM_THREADS" in os.environ else {"NUMBA_NUM_THREADS": "1"}
        with temporary_environment(worker_env):
            pool = multiprocessing.get_context("spawn").Pool(min(args.workers, len(names)))
        with pool:
            results = pool.starmap(run_variant, [(n, str(args.keep), args.seed) for n in names])
        run = {"commit": _commit(), "workers": min(args.workers, len(names)), "cpus": os.cpu_count()}
        fresh = {n: {**r, **run} for n, r in zip(names, results, strict=True)}
        earlier = json.loads(args.out.read_text()) if args.out.is_file() else {}
        seeds = earlier.get("seeds", {})
        if args.seed:  # another seed: the table's variants stay, the seeds table gets these
            kept = earlier["variants"]
            for n, r in fresh.items():
                seeds[n] = {**seeds.get(n, {}), str(args.seed): r}
            fresh = {}
        else:
            kept = earlier["variants"] if args.only and earlier else {}
        report = {"base": BASE, "variants": {n: fresh.get(n, kept.get(n)) for n in VARIANTS if n in fresh or n in kept},
                  **({"teacher_recovery": earlier["teacher_recovery"]} if "teacher_recovery" in earlier else {}),
                  **({"seeds": {n: seeds[n] for n in VARIANTS if n in seeds}} if seeds else {})}
        atomic_write_text(args.out, json.dumps(report, indent=1))
    if write_block(BLOCK, SOURCE, markdown_table(report), args.doc):
        print(f"wrote the table into {args.doc}")
    print(markdown_table(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
