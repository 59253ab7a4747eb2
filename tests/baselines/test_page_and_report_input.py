"""Commands that refresh a generated block of a page, or read a report to render it: a page that would not be
refreshed (missing, a directory, without the block, or a run the page does not show), a report without what the
table needs and a simulation too long to hold are each one line and exit 2, with nothing written."""

from __future__ import annotations

import json

import pytest

from softpvtol_gym.baselines.commands import model_figures, passivity_metrics, reproduce_paper
from tests.conftest import ROOT

COMMANDS = {"passivity-metrics": passivity_metrics.main, "reproduce-paper": reproduce_paper.main,
            "model-figures": model_figures.main}


def exit_2_with(command: str, argv: list[str], message: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        COMMANDS[command](argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


@pytest.fixture()
def pages(tmp_path):
    plain = tmp_path / "plain.md"
    plain.write_text("# a page without generated blocks\n")
    return {"missing": tmp_path / "nope.md", "directory": tmp_path, "no block": plain}


@pytest.mark.parametrize("command", ["passivity-metrics", "reproduce-paper"])
@pytest.mark.parametrize("which, message", [("missing", "no such file"), ("directory", "is a directory"),
                                            ("no block", "has no generated block")])
def test_a_page_that_would_not_be_refreshed_is_refused(command, which, message, pages, capsys):
    page = pages[which]
    before = page.read_text() if page.is_file() else None
    exit_2_with(command, ["--render-only", "--page", str(page)], f"--page {page}", capsys)
    assert (page.read_text() if page.is_file() else None) == before


def test_a_page_with_a_run_it_does_not_show_is_refused(tmp_path, capsys):
    page = tmp_path / "control.md"
    page.write_text((ROOT / "docs/control.md").read_text())
    exit_2_with("passivity-metrics", ["--episodes", "2", "--json", str(tmp_path / "p.json"), "--page", str(page)],
                "the page's table shows the default report", capsys)
    exit_2_with("reproduce-paper", ["--t-final", "5", "--out", str(tmp_path / "r"), "--page", str(page)],
                "the page's tables show the default run", capsys)
    assert not (tmp_path / "p.json").exists() and not (tmp_path / "r").exists()


@pytest.mark.parametrize("report", [{"meta": {}}, {"cells": []}, {"cells": {"hover/nominal": {"crash_rate": 0}}},
                                    {"cells": {}}])
def test_a_report_without_its_cells_is_one_error(report, tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(report))
    exit_2_with("passivity-metrics", ["--render-only", "--json", str(path)], "lacks its 'cells'", capsys)


@pytest.mark.parametrize("command", ["reproduce-paper", "model-figures"])
def test_a_simulation_too_long_to_hold_is_refused(command, tmp_path, capsys):
    exit_2_with(command, ["--t-final", "1e12"], "argument --t-final: must be <= 1000, got 1e+12", capsys)
