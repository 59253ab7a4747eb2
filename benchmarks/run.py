"""Benchmark suite: the speed of the Soft-PVTOL env measured against gymnasium's own envs.

    python benchmarks/run.py            # full run (~5 min), writes benchmarks/RESULTS.md, results.json and
                                        # time_to_beat.png, and the table of benchmarks/README.md
    python benchmarks/run.py --quick    # smoke run (~1 min), same tables, few repetitions, a short train.py

Every figure is a ratio measured in one process against reference envs timed in the same run,
interleaved (A B A B ...) and summarised by medians, because absolute times on a shared machine are
not stable. Items:

1. single-env step latency: gym.make("SoftPVTOL-v0") (defaults, random actions) vs Pendulum-v1 and
   Acrobot-v1;
2. vector-env throughput at N = 1 ... 65536 vs gymnasium's CartPoleVectorEnv and vs
   gym.make_vec(..., vectorization_mode="sync") of our env;
3. passivity controller + allocation vs one env step (single and batched): the residual mode's
   extra cost, PassivityPolicy.predict, PassivityController calls;
4. PPO with the default train.py configuration: env-steps/s and the share of wall time in the env;
5. cold start: import, first reset + step in a fresh process (warm numba cache), compile time with a
   cold cache;
6. time to beat the passivity controller: `python train.py` (the default agent) in a fresh process, the
   wall-clock seconds until its periodic held-out evaluation first beats the passivity controller, and of
   the whole run; its learning curve against wall-clock seconds is plotted to time_to_beat.png.

RESULTS.md is generated: do not edit it by hand, rerun the command.

This file is the driver; each item lives in a module of this folder: _env_speed.py (1-3), _training.py
(4, 6), _cold_start.py (5), _common.py (medians, tables, machine facts), _report.py (RESULTS.md,
the table of benchmarks/README.md).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # `python benchmarks/run.py`: the item modules are the package benchmarks/
    sys.path.insert(0, str(ROOT))

from benchmarks._cold_start import bench_cold_start  # noqa: E402
from benchmarks._common import machine_facts  # noqa: E402
from benchmarks._env_speed import bench_controller, bench_single, bench_vector  # noqa: E402
from benchmarks._report import (  # noqa: E402,F401  (README_*, readme_table: read by tests/benchmarks/test_benchmarks.py)
    README,
    README_END,
    README_START,
    readme_table,
    results_markdown,
    update_readme,
)
from benchmarks._training import (  # noqa: E402,F401  (time_to_beat: read by tests/benchmarks/test_benchmarks.py)
    TIME_TO_BEAT_GOAL,
    TRAIN_TOTAL_GOAL,
    bench_ppo,
    bench_time_to_beat,
    time_to_beat,
)
from softpvtol_gym.baselines.util.atomic import atomic_write_text  # noqa: E402

ITEMS = ("single", "vector", "controller", "ppo", "cold_start", "time_to_beat")
BENCHES = {"single": bench_single, "vector": bench_vector, "controller": bench_controller, "ppo": bench_ppo,
           "cold_start": bench_cold_start, "time_to_beat": bench_time_to_beat}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few repetitions (a smoke test, ~20 s)")
    parser.add_argument("--only", nargs="+", choices=ITEMS, help="run only these items")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks", help="folder for RESULTS.md and results.json")
    args = parser.parse_args(argv)
    items = args.only or list(ITEMS)
    command = "python benchmarks/run.py" + (" --quick" if args.quick else "") + (
        " --only " + " ".join(items) if args.only else "")
    facts = machine_facts()
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    results = {}
    for name in items:
        t0 = time.perf_counter()
        res = BENCHES[name](args.quick, args.out) if name == "time_to_beat" else BENCHES[name](args.quick)
        res["benchmark_seconds"] = time.perf_counter() - t0
        results[name] = res
        print(f"\n## {res['title']}\n\n{res['text']}\n", flush=True)
    facts["loadavg_end"] = list(os.getloadavg())
    atomic_write_text(args.out / "RESULTS.md", results_markdown(command, date, facts, results))
    payload = {"command": command, "date": date, "quick": args.quick, "machine": facts,
               "items": {k: {kk: vv for kk, vv in v.items() if kk != "text"} for k, v in results.items()}}
    atomic_write_text(args.out / "results.json", json.dumps(payload, indent=2, default=float) + "\n")
    print(f"wrote {args.out / 'RESULTS.md'} and {args.out / 'results.json'}")
    if not args.quick and not args.only and args.out.resolve() == (ROOT / "benchmarks").resolve():
        if update_readme(json.loads((args.out / "results.json").read_text())):
            print(f"updated the Performance table in {README}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
