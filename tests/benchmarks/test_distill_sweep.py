"""benchmarks/distill_sweep.py: its table in benchmarks/STUDIES.md is the one generated from the committed JSON, the
JSON holds every setting as the script defines it, and the leaderboard's distilled cells use the setting the
sweep found best."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from softpvtol_gym.baselines.leaderboard.spec import load_spec
from softpvtol_gym.baselines.util.blocks import read_block

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks import distill_sweep as bench  # noqa: E402
from tests.benchmarks._tables import check_render_only  # noqa: E402

COMMITTED = json.loads((ROOT / bench.SOURCE).read_text())


def test_studies_table_is_the_generated_one():
    assert read_block(bench.BLOCK, bench.SOURCE, bench.DOC) == \
        bench.markdown_table(COMMITTED).strip()


def test_the_committed_sweep_holds_every_setting_with_its_evaluation():
    assert list(COMMITTED["variants"]) == list(bench.VARIANTS) and COMMITTED["base"] == bench.BASE
    for name, v in COMMITTED["variants"].items():
        assert v["settings"] == bench.VARIANTS[name]
        assert set(v["evaluation"]) == set(v["settings"].get("tiers", bench.BASE["tiers"]))
        assert all(s["episodes"] == bench.BASE["eval_episodes"] for s in v["evaluation"].values())


def test_the_distilled_cell_uses_the_first_sweeps_best_setting_on_nominal():
    def steady(name):
        value = COMMITTED["variants"][name]["evaluation"]["nominal"]["mean_rms_position_error_steady"]
        return float("inf") if value is None else value

    best = min(bench.FIRST_SWEEP, key=steady)
    (cell,) = [d for d in load_spec()["distilled"] if d.get("variant") is None]
    assert {**bench.BASE, **bench.VARIANTS[best]} == {**bench.BASE, **cell["options"], "teacher": cell["teacher"],
                                                      "task": cell["task"], "tiers": [cell["tier"]]}


def test_render_only_writes_the_table_from_the_json(tmp_path, capsys):
    check_render_only(bench, COMMITTED, tmp_path, capsys)


def test_only_reruns_the_named_settings_and_keeps_the_others_with_their_runs(tmp_path, monkeypatch):
    class InProcess:  # a pool that runs the settings here, so that run_variant can be replaced
        def __init__(self, workers):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def starmap(self, fn, args):
            return [fn(*a) for a in args]

    monkeypatch.setattr(bench.multiprocessing, "get_context", lambda method: type("C", (), {"Pool": InProcess}))
    name = bench.FIRST_SWEEP[0]
    monkeypatch.setattr(bench, "run_variant", lambda n, scratch: {**COMMITTED["variants"][n], "seconds": 1.0})
    out, doc = tmp_path / "sweep.json", tmp_path / "page.md"
    out.write_text(json.dumps(COMMITTED))
    doc.write_text("# x\n")
    assert bench.main(["--only", name, "--workers", "1", "--out", str(out), "--doc", str(doc)]) == 0
    report = json.loads(out.read_text())
    assert list(report["variants"]) == list(COMMITTED["variants"])
    assert report["variants"][name]["seconds"] == 1.0 and report["variants"][name]["workers"] == 1
    others = [n for n in report["variants"] if n != name]
    assert all(report["variants"][n] == COMMITTED["variants"][n] for n in others)
