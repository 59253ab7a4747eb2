"""Per-robot compute: the latency of each kind of policy on one observation, like for like.

    python benchmarks/per_robot_compute.py --out benchmarks/per_robot_compute.json --readme benchmarks/README.md

Each policy acts on the observations of its own closed loop (one episode, ``--steps`` control steps of
``track_random``, nominal tier, seed 1,000,000), and
:func:`softpvtol_gym.baselines.evaluation.compute_us_single` times ``predict`` on one observation (obs_dim,) at
a time over them, in order, each pass starting the policy's memory anew (an MPC's warm start does each step's
work as in its closed loop), in one thread (torch on one thread). The MPC's own timer gives its step's median, p99
and max over every call of the run. The policies: the passivity controller (the env's
default loop, ``bounded``), its integral loop, the dynamically extended loop (actuators mode), the nonlinear MPC
(``MPCPolicy``, actuators mode; also on the ``hard`` tier, whose noisy observations cost its QP more
interior-point iterations), and a learned
2 x 64 MLP (the committed checkpoint ``ppo_residual_track_random_nominal/seed_0``, residual mode, normalised
observations) three ways: ``LearnedPolicy(..., inference="lean")`` (the compiled float64 pass), ``inference=
"torch"`` (SB3's ``predict`` calls), and SB3's own ``model.predict`` after ``VecNormalize.normalize_obs``.
The cases are interleaved (one pass of each, ``--rounds`` times) so that a change of the machine's load
reaches all of them; the figure is the median over rounds of each round's median, with the rounds' range, and
the lean path's ratio to the integral loop is the median over rounds of the ratio measured in one round.
A residual student's ``predict`` is its correction alone: the robot also runs the loop it corrects, and
``small_student_with_loop_over_integral`` counts both (one loop more than ``small_student_over_integral``).
``--readme`` replaces the generated table (block ``per_robot_compute.py``) in the files given.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks._common import machine_facts  # noqa: E402
from softpvtol_gym import MPCPolicy, PassivityPolicy, SoftPVTOLVectorEnv  # noqa: E402
from softpvtol_gym.baselines.evaluation import (  # noqa: E402
    EVAL_SEED_OFFSET,
    compute_us_single,
    episode_observations,
)
from softpvtol_gym.baselines.training.policy import LearnedPolicy  # noqa: E402
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402
from softpvtol_gym.baselines.util.blocks import write_block  # noqa: E402
from softpvtol_gym.envs.config import EnvConfig  # noqa: E402

SOURCE = "benchmarks/per_robot_compute.json"
BLOCK = "per_robot_compute.py"
CHECKPOINT = "results/leaderboard_runs/ppo_residual_track_random_nominal/seed_0"
#: the leaderboard's bounded robust student (distilled from the MPC): a 2 x 256 MLP on 4 stacked observations,
#: a bounded residual on the saturated integral loop
STUDENT = "results/leaderboard_runs/distilled-mpc-robust-bounded_track_random_nominal/seed_0"
#: the same students at 2 x 64
SMALL_STUDENT = "results/leaderboard_runs/distilled-mpc-robust-bounded-small_track_random_nominal/seed_0"
TASK, TIER = "track_random", "nominal"
#: (name, what it is) in the order of the table
CASES = (
    ("passivity", "`PassivityPolicy`, the env's default loop (bounded)"),
    ("integral", "`PassivityPolicy`, the integral loop"),
    ("extended", "`ExtendedPolicy`, the dynamically extended loop"),
    ("mpc", "`MPCPolicy`, the nonlinear MPC (one real-time iteration, PIQP)"),
    ("mpc-hard", "`MPCPolicy` on the `hard` tier (noisy observations: more interior-point iterations)"),
    ("learned-lean", "learned 2 x 64 MLP: `LearnedPolicy` (default, `inference=\"lean\"`)"),
    ("learned-torch", "learned 2 x 64 MLP: `LearnedPolicy(..., inference=\"torch\")` (SB3's `predict` calls)"),
    ("learned-sb3", "learned 2 x 64 MLP: SB3's `model.predict` after `VecNormalize.normalize_obs`"),
    ("student-lean", "the bounded robust student: 2 x 256 MLP on 4 observations, a residual on the integral loop "
                     "(`LearnedPolicy`, lean)"),
    ("student-small-lean", "the same bounded robust student at 2 x 64 (`LearnedPolicy`, lean)"),
)


class SB3Predict:
    """SB3's own path, as a user of SB3 runs a checkpoint: ``model.predict(vecnorm.normalize_obs(obs))``."""

    def __init__(self, model, vecnorm):
        self.model, self.vecnorm = model, vecnorm

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        return self.model.predict(self.vecnorm.normalize_obs(observation), deterministic=deterministic)


def build_cases(steps: int) -> dict:
    """name -> (policy, its observations)."""
    cases = {}
    for name, loop in (("passivity", "bounded"), ("integral", "integral"), ("extended", "extended")):
        kw = {"allocation": "exact", "controller_loop": loop}
        probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=TASK, **kw)
        policy = PassivityPolicy.from_env(probe)
        cases[name] = (policy, episode_observations(policy, "actuators", TASK, TIER, EVAL_SEED_OFFSET, kw, steps=steps))
    for name, tier in (("mpc", TIER), ("mpc-hard", "hard")):
        policy = MPCPolicy(EnvConfig(task=TASK, tier=tier, action_mode="actuators"))
        cases[name] = (policy, episode_observations(policy, "actuators", TASK, tier, EVAL_SEED_OFFSET, steps=steps))
    lean, config = LearnedPolicy.load(ROOT / CHECKPOINT)
    obs = episode_observations(lean, config.action_mode, TASK, TIER, EVAL_SEED_OFFSET, config.eval_env_kwargs(),
                               steps=steps)
    torch_path = LearnedPolicy(lean.model, lean.vecnorm, inference="torch")
    cases["learned-lean"] = (lean, obs)
    cases["learned-torch"] = (torch_path, obs)
    cases["learned-sb3"] = (SB3Predict(lean.model, lean.vecnorm), obs)
    for name, folder in (("student-lean", STUDENT), ("student-small-lean", SMALL_STUDENT)):
        student, config = LearnedPolicy.load(ROOT / folder)
        cases[name] = (student, episode_observations(student, config.action_mode, TASK, TIER, EVAL_SEED_OFFSET,
                                                     config.eval_env_kwargs(), steps=steps))
    return cases


def median_ratio(per_round: dict, top: str, bottom: str) -> float:
    """The median over rounds of case ``top``'s time over case ``bottom``'s, each ratio within one round."""
    return float(np.median([a / b for a, b in zip(per_round[top], per_round[bottom])]))


def measure(steps: int, rounds: int) -> dict:
    cases = build_cases(steps)
    per_round = {name: [] for name in cases}
    for _ in range(rounds):
        for name, (policy, obs) in cases.items():
            per_round[name].append(compute_us_single(policy, obs, repeats=1))
    timer = ("solves", "solve_ms_median", "solve_ms_p99", "solve_ms_max")
    return {
        "mpc_solver": {name: {k: cases[name][0].stats[k] for k in timer} for name in ("mpc", "mpc-hard")},
        "us": {name: {"median": float(np.median(v)), "min_round": float(min(v)), "max_round": float(max(v)),
                      "rounds": [round(x, 3) for x in v], "observations": int(len(cases[name][1]))}
               for name, v in per_round.items()},
        "lean_over_integral": median_ratio(per_round, "learned-lean", "integral"),
        "student_over_integral": median_ratio(per_round, "student-lean", "integral"),
        "small_student_over_integral": median_ratio(per_round, "student-small-lean", "integral"),
        # a residual student runs on its base loop: a robot computes both, the loop's command and the correction
        "small_student_with_loop_over_integral": 1.0 + median_ratio(per_round, "student-small-lean", "integral"),
        "torch_over_lean": median_ratio(per_round, "learned-torch", "learned-lean"),
    }


def markdown_table(report: dict) -> str:
    facts = report["machine"]
    lines = [f"From `{report['command']}`, {facts['cores']} cores, "
             f"load average {facts['loadavg_start'][0]:.2f} at the start and {report['loadavg_end'][0]:.2f} at the "
             f"end; {report['rounds']} rounds of {report['steps']} observations per policy.",
             "",
             "| policy | us per observation: median (rounds' range) |",
             "|---|---|"]
    for name, what in CASES:
        m = report["us"][name]
        lines.append(f"| {what} | {m['median']:.1f} ({m['min_round']:.1f}-{m['max_round']:.1f}) |")
    lines += ["", f"The lean path / the integral loop, per round: {report['lean_over_integral']:.2f}x; SB3's "
                  f"`predict` calls (`inference=\"torch\"`) / the lean path: {report['torch_over_lean']:.0f}x; "
                  f"the bounded robust student / the integral loop: {report['student_over_integral']:.1f}x "
                  f"(at 2 x 64: {report['small_student_over_integral']:.1f}x; with the integral loop it corrects, "
                  f"which the robot runs too, {report['small_student_with_loop_over_integral']:.1f}x)."]
    for name, label in (("mpc", "nominal"), ("mpc-hard", "hard")):
        m = report["mpc_solver"][name]
        lines += ["", f"The MPC's step on the {label} tier by its own timer, over all {m['solves']} calls of the run: "
                     f"median {m['solve_ms_median']:.2f} ms, p99 {m['solve_ms_p99']:.2f} ms, max "
                     f"{m['solve_ms_max']:.1f} ms."]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=500, help="observations per policy (default 500)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved rounds (default 7)")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON here")
    ap.add_argument("--readme", type=Path, nargs="*", default=[], help="replace the generated table in these files")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        ap.error(f"--steps and --rounds must be >= 1, got {args.steps} and {args.rounds}")
    facts = machine_facts()
    t0 = time.perf_counter()
    argv = sys.argv[1:] if argv is None else list(argv)
    report = {"command": " ".join(["python benchmarks/per_robot_compute.py", *argv]),
              "machine": facts, "steps": args.steps, "rounds": args.rounds, "task": TASK, "tier": TIER,
              "checkpoint": CHECKPOINT, "student": STUDENT, "small_student": SMALL_STUDENT,
              **measure(args.steps, args.rounds),
              "loadavg_end": list(os.getloadavg())}
    report["seconds"] = round(time.perf_counter() - t0, 1)
    table = markdown_table(report)
    print(table)
    if args.out is not None:
        atomic_write_text(args.out, json.dumps(report, indent=1) + "\n")
    for path in args.readme:
        if not write_block(BLOCK, SOURCE, table, path):
            print(f"{path}: no block {BLOCK!r}; nothing written there", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
