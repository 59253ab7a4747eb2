"""Integration error of the paper's actuated loop at the paper's step (docs/model.md, difference #12).

    softpvtol model-figures [--t-final 10] [--json results/model_figures.json]

(in a source checkout ``python baselines/model_figures.py`` writes ``results/model_figures.json``)

The paper integrates its closed loop with Simulink's ode5 at a fixed 0.01 s and this package's
reproduction with classical RK4 at 0.01 s; docs/model.md used to say the two "agree to plotting
accuracy". This script measures how far a 0.01 s RK4 solution of the paper's continuous-time actuated
loop is from the converged solution: the same loop (``PassivityController`` "paper" loop, its algebraic
loop solved to 1e-10 rad in at most ``--passes`` passes from the allocation at t = 0, evaluated as a pure
function of (t, q, qdot) at every RK4 stage) integrated by RK4 at 0.01 s, 0.001 s and 0.0005 s from the
paper's initial state. The 0.001 / 0.0005 s pair bounds the reference's own error. Output: the largest
|x| and |z| differences and when they occur, and the largest change of the arm references (q_l^d, q_r^d)
between two 0.01 s steps (with the printed arctan allocation they jumped by up to 2.7 rad and an
adaptive DOP853 run, rtol = atol = 1e-7, did not finish 4 s of simulated time in 10 minutes; hence
fixed steps).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.figures.model import compare
from softpvtol_gym.baselines.util.args import (
    Parser,
    check_output_file,
    command_main,
    float_arg,
    int_arg,
    refuse_overwrite,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.paths import Layout

Q0 = np.array([5.0, 0.0, 0.2 * np.pi, 0.01 * np.pi, -0.15 * np.pi])


#: the longest simulation the command accepts [s]: the paper simulates 40 s; the trajectories are kept in memory
MAX_T_FINAL_S = 1000.0

def _main(argv, layout: Layout, prog: str) -> int:
    ap = Parser(prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--t-final", type=float_arg(0.0, MAX_T_FINAL_S, lo_open=True), default=10.0,
                    help=f"simulated time [s] (default 10; at most {MAX_T_FINAL_S:g})")
    ap.add_argument("--passes", type=int_arg(1), default=50, help="fixed-point passes of the algebraic loop")
    ap.add_argument("--json", type=Path, default=layout.results / "model_figures.json", help="default: %(default)s")
    ap.add_argument("--force", action="store_true", help="let a run with other settings overwrite the default report")
    args = ap.parse_args(argv)
    refuse_overwrite(ap, args, ("t_final", "passes"), [(args.json, ap.get_default("json"), "--json")])
    check_output_file(args.json, force=True, option="--json")  # before simulating
    t0 = time.perf_counter()
    result = compare(args.t_final, args.passes)
    for name, r in result.items():
        if not isinstance(r, dict):
            print(f"{name}: {r}")
            continue
        print(f"{name}: max |dx| {r['max_abs_x_m']:.4g} m at t = {r['t_of_max_x_s']:.2f} s, "
              f"max |dz| {r['max_abs_z_m']:.4g} m at t = {r['t_of_max_z_s']:.2f} s")
    report = {"command": "python baselines/model_figures.py", "t_final_s": args.t_final, "passes": args.passes,
              "comparisons": {k: v for k, v in result.items() if isinstance(v, dict)},
              "arm_reference_jumps": {k: v for k, v in result.items() if not isinstance(v, dict)},
              "wall_time_s": round(time.perf_counter() - t0, 1)}
    atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


main = command_main("model_figures.py", _main,
                    "``softpvtol model-figures``: the report under ``layout`` (default: ``./results/``).")
