"""benchmarks/per_robot_compute.py: its README table is the one generated from the committed JSON, the committed
figures say what the README claims (every kind measured, the lean path within 2x of the integral loop), and a
short run works end to end."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from softpvtol_gym.baselines.util.blocks import read_block

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks import per_robot_compute as bench  # noqa: E402

COMMITTED = json.loads((ROOT / bench.SOURCE).read_text())


def test_readme_table_is_the_generated_one():
    assert read_block(bench.BLOCK, bench.SOURCE, ROOT / "benchmarks" / "README.md") == \
        bench.markdown_table(COMMITTED).strip()


def test_committed_figures_cover_every_kind_and_the_lean_path_is_within_2x_of_the_integral_loop():
    assert set(COMMITTED["us"]) == {name for name, _ in bench.CASES}
    assert all(m["observations"] == COMMITTED["steps"] and m["median"] > 0 for m in COMMITTED["us"].values())
    assert COMMITTED["lean_over_integral"] <= 2.0
    assert COMMITTED["us"]["learned-torch"]["median"] > COMMITTED["us"]["learned-lean"]["median"]
    # the bounded robust student's 2 x 256 network on 4 observations costs more than the 2 x 64 one, and its ratio
    # is the one the guide quotes
    assert COMMITTED["us"]["student-lean"]["median"] > COMMITTED["us"]["learned-lean"]["median"]
    assert COMMITTED["student_over_integral"] > COMMITTED["lean_over_integral"]
    # the same student at 2 x 64 costs less than at 2 x 256, more than the 2 x 64 MLP on one observation
    assert COMMITTED["us"]["learned-lean"]["median"] < COMMITTED["us"]["student-small-lean"]["median"] \
        < COMMITTED["us"]["student-lean"]["median"]
    ratios = ("lean_over_integral", "small_student_over_integral", "student_over_integral")
    assert COMMITTED[ratios[0]] < COMMITTED[ratios[1]] < COMMITTED[ratios[2]]
    # the small student with the loop it corrects: one loop more than its own ratio
    assert abs(COMMITTED["small_student_with_loop_over_integral"] - 1.0 - COMMITTED[ratios[1]]) < 1e-12


def test_a_short_run_writes_the_report_and_the_table(tmp_path):
    readme = tmp_path / "README.md"
    start, end = (f"<!-- {bench.BLOCK}: table start (generated from {bench.SOURCE}, do not edit) -->",
                  f"<!-- {bench.BLOCK}: table end -->")
    readme.write_text(f"# x\n\n{start}\nold\n{end}\n")
    out = tmp_path / "report.json"
    assert bench.main(["--steps", "5", "--rounds", "1", "--out", str(out), "--readme", str(readme)]) == 0
    report = json.loads(out.read_text())
    assert report["rounds"] == 1 and all(m["observations"] == 5 for m in report["us"].values())
    assert read_block(bench.BLOCK, bench.SOURCE, readme) == bench.markdown_table(report).strip()
