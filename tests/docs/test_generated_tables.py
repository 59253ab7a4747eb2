"""Generated tables (README.md and docs/ pages) are the ones the commands generate from their committed
results, and those results say what the pages claim (passivity metrics, the paper reproduction and its
steady-state study, the leaderboard's headline and the README's summary of it)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from softpvtol_gym.baselines.commands import passivity_metrics, reproduce_paper
from softpvtol_gym.baselines.leaderboard import render as leaderboard
from softpvtol_gym.baselines.util import blocks as readme
from tests.conftest import LAYOUT, LEADERBOARD_JSON

ROOT = Path(__file__).resolve().parents[2]
PAPER = json.loads((ROOT / reproduce_paper.README_SOURCE).read_text())
METRICS = json.loads((ROOT / passivity_metrics.README_SOURCE).read_text())
BOARD = json.loads(LEADERBOARD_JSON.read_text())
CONTROL, BOARD_PAGE = LAYOUT.doc("control.md"), LAYOUT.doc("leaderboard.md")


@pytest.mark.parametrize("name, source, page, table", [
    ("passivity_metrics.py", passivity_metrics.README_SOURCE, CONTROL,
     lambda: passivity_metrics.metrics_table(METRICS)),
    ("reproduce_paper.py loops", reproduce_paper.README_SOURCE, CONTROL, lambda: reproduce_paper.loops_table(PAPER)),
    ("reproduce_paper.py steady state", reproduce_paper.README_SOURCE, CONTROL,
     lambda: reproduce_paper.steady_state_table(PAPER["steady_state"])),
    (*leaderboard.HEADLINE_BLOCK, BOARD_PAGE, lambda: "\n".join(leaderboard.headline_markdown(BOARD, heading=False))),
    (*leaderboard.SUMMARY_BLOCK, LAYOUT.readme, lambda: leaderboard.summary_markdown(BOARD)),
])
def test_generated_table_is_the_committed_one(name, source, page, table):
    assert readme.read_block(name, source, page) == table().strip()


def test_the_readme_summary_is_short():
    summary = leaderboard.summary_markdown(BOARD)
    assert len(summary.splitlines()) <= 8 and "docs/leaderboard.md" in summary


def test_write_block_replaces_only_the_block(tmp_path):
    path = tmp_path / "README.md"
    start, end = readme.markers("x", "y.json")
    path.write_text(f"a\n{start}\nold\n{end}\nb\n")
    assert readme.write_block("x", "y.json", "| new |", path)
    assert path.read_text() == f"a\n{start}\n| new |\n{end}\nb\n"
    assert readme.read_block("x", "y.json", path) == "| new |"
    assert not readme.write_block("other", "y.json", "t", path)
    with pytest.raises(KeyError):
        readme.read_block("other", "y.json", path)


def test_committed_paper_reproduction_backs_the_readme_claims():
    loops = PAPER["loops"]
    for name, m in loops.items():
        if not name.startswith("ideal"):  # every actuated step solved the algebraic loop
            assert m["algebraic_loop"]["residual_max_rad"] <= 1e-10, name
    x_rms = {k: v["tracking_error"]["20-40s"]["x"]["rms"] for k, v in loops.items()}
    assert 4e-2 < x_rms["paper"] < 8e-2 and x_rms["improved"] < 1e-3 and x_rms["bounded"] < 1e-3
    steady = PAPER["steady_state"]["loops"]
    assert len(PAPER["steady_state"]["initial_states"]) == 6
    for loop in ("improved", "bounded"):
        floors = [steady[loop]["stage"][f"{dt:g}"]["worst_max_abs_xz"] for dt in reproduce_paper.STEADY_DTS]
        # a floor, proportional to dt (not convergence): halving dt about halves it
        assert all(f > 1e-7 for f in floors), floors
        assert 1.5 < floors[0] / floors[1] < 2.5, floors
    # the ideal loop evaluated at every stage is still decaying at 60-80 s (not a floor)
    assert steady["ideal"]["stage"]["0.01"]["worst_max_abs_xz"] < 1e-7


def test_committed_passivity_metrics_use_the_default_loop():
    assert METRICS["loop"] == "bounded"
    assert METRICS["cells"]["track_paper/nominal"]["crash_rate"] == 0.0
