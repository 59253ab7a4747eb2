"""benchmarks/robust_students.py: its table in benchmarks/STUDIES.md is the one generated from the committed JSON, the
JSON holds every variant as the script defines it with every task and tier of the mixture, and the section's words
say what the JSON shows."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from softpvtol_gym.baselines.util.blocks import read_block

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from benchmarks import robust_students as bench  # noqa: E402
from tests.benchmarks._tables import check_render_only  # noqa: E402

COMMITTED = json.loads((ROOT / bench.SOURCE).read_text())
VARIANTS = COMMITTED["variants"]
CELLS = [t if i == 0 else f"{task} {t}" for i, task in enumerate([bench.BASE["task"], *bench.BASE["also_tasks"]])
         for t in bench.BASE["tiers"]]


def crashes(summary: dict) -> int:
    return round(summary["crash_rate"] * summary["episodes"])


def test_studies_table_is_the_generated_one():
    assert read_block(bench.BLOCK, bench.SOURCE, bench.DOC) == bench.markdown_table(COMMITTED).strip()


def test_the_committed_probe_holds_every_variant_on_every_task_and_tier():
    assert list(VARIANTS) == list(bench.VARIANTS) and COMMITTED["base"] == bench.BASE
    for name, v in VARIANTS.items():
        assert v["settings"] == bench.VARIANTS[name]
        assert list(v["evaluation"]) == CELLS and list(v["teacher"]) == CELLS
        assert all(s["episodes"] == bench.BASE["eval_episodes"] for s in v["evaluation"].values())
        assert (v.get("labels_at_clip") is not None) == ("residual_on" in v["settings"])


BOUNDED = ("tier mixture, history 4, privileged, turned starts, 5 rounds, bounded residual ({}) on the saturated "
           "integral loop")


def test_only_the_bounded_residual_reaches_the_issues_crash_goal_and_the_page_says_so():
    """In words: every variant but the residual bounded to 0.25 crashes where the MPC does not (hover noisy and hard,
    model_gap); privileged labels remove the crash on track_random noisy."""
    text = (ROOT / "benchmarks" / "STUDIES.md").read_text()
    section = text[text.index("## Robust students"):text.index("## Running on Ray")]
    reached = [name for name, v in VARIANTS.items()
               if not [c for c in CELLS if crashes(v["evaluation"][c]) > crashes(v["teacher"][c])]]
    assert reached == [BOUNDED.format(0.25)]
    assert all(crashes(VARIANTS[n]["evaluation"]["hover noisy"]) >= 1 for n in VARIANTS if n not in reached)
    assert crashes(VARIANTS["tier mixture, history 4"]["evaluation"]["noisy"]) == 1
    assert crashes(VARIANTS["tier mixture, history 4, privileged"]["evaluation"]["noisy"]) == 0
    assert "none but the bounded residual (0.25) reaches the issue's crash goal on them" in " ".join(section.split())


def test_the_bounded_residual_crashes_nowhere_and_the_page_says_what_it_costs():
    """In words: bounded to 0.25 no crash in 80 (the MPC 1), bounded to 0.5 two; half the labels at the clip; its
    last half on track_random and hover nominal and track_random hard against the MPC's."""
    section = " ".join((ROOT / "benchmarks" / "STUDIES.md").read_text().split())
    quarter, half = VARIANTS[BOUNDED.format(0.25)], VARIANTS[BOUNDED.format(0.5)]
    assert quarter["settings"]["residual_scale"] == 0.25 and half["settings"]["residual_scale"] == 0.5
    assert sum(crashes(quarter["evaluation"][c]) for c in CELLS) == 0
    assert sum(crashes(quarter["teacher"][c]) for c in CELLS) == 1 == crashes(quarter["teacher"]["hover model_gap"])
    assert {c for c in CELLS if crashes(half["evaluation"][c])} == {"hover noisy", "hover hard"}
    clip = quarter["labels_at_clip"]

    def sci(value: float) -> str:  # 1.5e-3: one decimal, the exponent without its leading zero
        mantissa, exponent = f"{value:.1e}".split("e")
        return f"{mantissa}e{int(exponent)}"

    steady, mpc = ({c: sci(quarter[side][c]["mean_rms_position_error_steady"]) for c in ("nominal", "hover nominal",
                                                                                       "hard")}
                   for side in ("evaluation", "teacher"))
    assert (f"{100 * min(clip):.0f}-{100 * max(clip):.0f} % of its labels sit at the clip, and its last half is "
            f"{steady['nominal']} m on track_random nominal and {steady['hover nominal']} m on hover nominal (the MPC "
            f"{mpc['nominal']} and {mpc['hover nominal']} m), {steady['hard']} m on track_random hard (the MPC "
            f"{mpc['hard']} m)") in section


def test_render_only_writes_the_table_from_the_json(tmp_path, capsys):
    check_render_only(bench, COMMITTED, tmp_path, capsys)


def test_the_saturated_base_removes_the_clip_and_the_noisy_crash_and_the_page_says_what_it_costs():
    """In words: on the saturated base few labels clip (against 42-43 % of the arm labels on the unsaturated one),
    no track_random noisy episode crashes, and it crashes more than the actuator students on hard and model_gap."""
    text = (ROOT / "benchmarks" / "STUDIES.md").read_text()
    section = text[text.index("## Robust students"):text.index("## Running on Ray")]
    plain = VARIANTS["tier mixture, history 4, privileged"]["evaluation"]
    unsaturated = VARIANTS["tier mixture, history 4, privileged, residual on the integral loop"]
    saturated = VARIANTS["tier mixture, history 4, privileged, residual on the saturated integral loop"]
    assert max(saturated["labels_at_clip"]) <= 0.02 < 0.4 < min(unsaturated["labels_at_clip"][2:])
    assert crashes(saturated["evaluation"]["noisy"]) == 0 and crashes(unsaturated["evaluation"]["noisy"]) == 8
    assert saturated["evaluation"]["noisy"]["mean_rms_position_error_steady"] < saturated["teacher"]["noisy"][
        "mean_rms_position_error_steady"]
    for cell in ("hard", "model_gap"):
        assert crashes(saturated["evaluation"][cell]) == 4 > crashes(plain[cell])
    assert "1-2 % of the labels clip" in section and "4 of 8 on track_random hard and model_gap" in section


def test_recovery_data_removes_most_crashes_and_the_page_says_where_it_still_crashes():
    """In words: the privileged actuator student with turned starts crashes in 2 of 80 episodes (hover noisy, where
    the MPC does not; hover model_gap, as the MPC), the same student without them in 10; the teacher recovers from
    turned starts in all but one of 8 on each hard tier."""
    text = (ROOT / "benchmarks" / "STUDIES.md").read_text()
    section = text[text.index("## Robust students"):text.index("## Running on Ray")]
    turned = VARIANTS["tier mixture, history 4, privileged, turned starts, 5 rounds"]
    plain = VARIANTS["tier mixture, history 4, privileged"]
    assert sum(crashes(turned["evaluation"][c]) for c in CELLS) == 2
    assert sum(crashes(plain["evaluation"][c]) for c in CELLS) == 10
    worse = [c for c in CELLS if crashes(turned["evaluation"][c]) > crashes(turned["teacher"][c])]
    assert worse == ["hover noisy"] and crashes(turned["evaluation"]["hover model_gap"]) == 1
    recovery = COMMITTED["teacher_recovery"]
    assert list(recovery) == [c if " " in c else f"track_random {c}" for c in CELLS]
    assert {c: r["crashes"] for c, r in recovery.items() if r["crashes"]} == {"track_random hard": 1, "hover hard": 1}
    assert "crashes in 2 of the\n  80 episodes" in section and "all but 1 of 8 on each hard tier" in section


def _summary(crashed: int, episodes: int = 8) -> dict:
    return {"crash_rate": crashed / episodes, "episodes": episodes}


def test_the_seeds_table_counts_each_seeds_crashes_and_their_sum():
    cells = ["nominal", *bench.CRASH_CELLS]
    run = {"evaluation": {c: _summary(i % 3) for i, c in enumerate(cells)}, "teacher": {c: _summary(0) for c in cells}}
    other = {"evaluation": {c: _summary(1) for c in cells}, "teacher": {c: _summary(c == "hover hard") for c in cells}}
    report = {"base": bench.BASE, "variants": {"v": run}, "seeds": {"v": {"2": other}}}
    rows = [line for line in bench.seeds_table(report).splitlines() if line.startswith("| v |")]
    assert rows == ["| v | 0 | 1 (0) | 2 (0) | 0 (0) | 1 (0) | 2 (0) | 0 (0) | 6 (0) of 56 |",
                    "| v | 2 | 1 (0) | 1 (0) | 1 (0) | 1 (0) | 1 (1) | 1 (0) | 7 (1) of 56 |",
                    "| v | all 2 | 2 (0) | 3 (0) | 1 (0) | 2 (0) | 3 (1) | 1 (0) | 13 (1) of 112 |"]


def test_leaderboard_seeds_are_taken_only_with_the_variants_settings(tmp_path):
    import dataclasses

    import pytest

    cell = tmp_path / "cell"
    with pytest.raises(SystemExit, match="no runs of seed 1 and up"):
        bench.leaderboard_seeds(cell)
    config = json.loads(json.dumps(dataclasses.asdict(bench.variant_config(bench.LEADERBOARD_VARIANT, 1))))
    del config["residual_scale"]  # a run recorded before the setting existed: its value then
    cells = {c: {"student": _summary(1), "teacher": _summary(0)} for c in CELLS}
    record = {"config": config, "seconds": 12.0,
              "rounds": [{"loss_last_epoch": 1.0, "aggregate": 10, "evaluation": cells}]}
    (cell / "seed_1").mkdir(parents=True)
    (cell / "seed_1" / "distill.json").write_text(json.dumps(record))
    (taken,) = bench.leaderboard_seeds(cell).values()
    assert taken["seconds"] == 12.0 and taken["evaluation"]["hover hard"] == _summary(1)
    record["config"]["history"] = 20
    (cell / "seed_1" / "distill.json").write_text(json.dumps(record))
    with pytest.raises(SystemExit, match="seed_1: its settings are not those of the variant"):
        bench.leaderboard_seeds(cell)


def test_the_committed_seeds_are_runs_of_their_variants_and_the_page_counts_their_hover_crashes():
    """The seeds table's runs have their variant's settings and every cell; in words, the leaderboard cell's five
    seeds crash in 11, 13 and 10 of 40 hover noisy, hard and model_gap episodes."""
    seeds = COMMITTED["seeds"]
    assert set(seeds) <= set(VARIANTS) and bench.LEADERBOARD_VARIANT in seeds
    for name, by_seed in seeds.items():
        assert by_seed and all(int(seed) > 0 for seed in by_seed)
        for v in by_seed.values():
            assert v["settings"] == bench.VARIANTS[name] and list(v["evaluation"]) == CELLS
    runs = [VARIANTS[bench.LEADERBOARD_VARIANT], *seeds[bench.LEADERBOARD_VARIANT].values()]
    assert len(runs) == 5
    counts = [sum(crashes(v["evaluation"][f"hover {tier}"]) for v in runs) for tier in ("noisy", "hard", "model_gap")]
    section = " ".join((ROOT / "benchmarks" / "STUDIES.md").read_text().split())
    assert (f"they crash in {counts[0]} of 40 hover noisy, {counts[1]} of 40 hover hard and {counts[2]} of 40 hover "
            "model_gap episodes (the seeds table above") in section


def test_the_bounded_residual_crashes_nowhere_on_two_seeds_and_the_page_says_so():
    by_seed = {"0": VARIANTS[BOUNDED.format(0.25)], **COMMITTED["seeds"][BOUNDED.format(0.25)]}

    def count(seeds: list[str]) -> tuple[int, int]:
        return tuple(sum(crashes(by_seed[s][k][c]) for s in seeds for c in CELLS) for k in ("evaluation", "teacher"))

    student, teacher = count(["0", "1"])  # the probe's own two seeds
    assert student == 0
    section = " ".join((ROOT / "benchmarks" / "STUDIES.md").read_text().split())
    assert f"0 in {2 * len(CELLS) * 8} over two seeds, the MPC {teacher}" in section
    assert sorted(by_seed, key=int) == ["0", "1", "2", "3", "4"]  # with the leaderboard cell's seeds 2-4
    student, teacher = count(list(by_seed))
    assert f"its five seeds crash in {student} of {5 * len(CELLS) * 8}" in section
    assert f"the MPC in {teacher}; the seeds table above" in section


def test_a_seed_of_the_probe_keeps_its_run_and_a_leaderboard_run_that_differs_is_named():
    run = {"evaluation": {"hover hard": _summary(1)}, "teacher": {"hover hard": _summary(0)}, "seconds": 1.0}
    later = {**run, "seconds": 2.0}  # the same students, timed again
    assert bench.merge_seeds({"1": run}, {"1": later, "2": later}) == ({"1": run, "2": later}, [])
    other = {**run, "evaluation": {"hover hard": _summary(0)}}
    assert bench.merge_seeds({"1": run}, {"1": other}) == ({"1": run}, ["1"])


def test_more_history_on_the_bounded_residual_does_no_better_and_the_page_says_so():
    """In words: 0.1 s and 0.2 s of history on the bounded residual (0.25) crash on hover where 0.04 s does not;
    their last half on track_random mismatch and model_gap."""
    section = " ".join((ROOT / "benchmarks" / "STUDIES.md").read_text().split())
    longer = {h: VARIANTS[f"tier mixture, history {h} ({h / 100:.1f} s), privileged, turned starts, 5 rounds, bounded "
                          f"residual (0.25) on the saturated integral loop"] for h in (10, 20)}
    short = VARIANTS[BOUNDED.format(0.25)]
    assert all(v["settings"]["history"] == h for h, v in longer.items())
    hover = {h: {c: crashes(v["evaluation"][c]) for c in ("hover noisy", "hover hard")} for h, v in longer.items()}
    assert hover == {10: {"hover noisy": 1, "hover hard": 0}, 20: {"hover noisy": 1, "hover hard": 1}}
    assert sum(crashes(short["evaluation"][c]) for c in CELLS) == 0

    def half(v, cell):
        mantissa, exponent = f"{v['evaluation'][cell]['mean_rms_position_error_steady']:.1e}".split("e")
        return f"{mantissa}e{int(exponent)}"

    assert (f"(track_random mismatch {half(short, 'mismatch')} m at 0.04 s, {half(longer[10], 'mismatch')} and "
            f"{half(longer[20], 'mismatch')} m; model_gap {half(short, 'model_gap')}, {half(longer[10], 'model_gap')} "
            f"and {half(longer[20], 'model_gap')} m): the leaderboard's students keep 4 observations") in section
