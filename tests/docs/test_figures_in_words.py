"""Figures written in words say what the committed leaderboard says: the README's headline in words and the
leaderboard figures of docs/baselines.md's prose. Each figure is computed here from the leaderboard's aggregate
rows (the summary that ships with the package, equal to the aggregates of ``results/leaderboard.json``) and looked
up in the text, so a re-scored leaderboard that moves a figure fails here until the sentence is rewritten."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softpvtol_gym.baselines.leaderboard.headline import headline, tolerance_headline, verdict, window_headline
from softpvtol_gym.baselines.leaderboard.spec import is_learned
from softpvtol_gym.baselines.leaderboard.stats import WINDOWS as WINDOW_METRICS
from softpvtol_gym.baselines.leaderboard.summary import SUMMARY_FILE
from softpvtol_gym.envs.tiers import get_tier
from tests.conftest import LAYOUT

BOARD = json.loads(SUMMARY_FILE.read_text())
ROWS = BOARD["aggregates"]
WINDOWS = window_headline(BOARD)
NUMBER_WORDS = dict(enumerate(("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")))


def _in_words() -> str:
    """The README's bullets under the headline table, one line (Markdown line breaks as spaces)."""
    text = LAYOUT.readme.read_text()
    start = text.index("In words:", text.index("## Headline result"))
    return " ".join(text[start:text.index("\nFigures:", start)].split())


WORDS = _in_words()
BASELINES_PAGE = " ".join(LAYOUT.doc("baselines.md").read_text().split())


def _row(entry: str, task: str, tier: str) -> dict:
    (row,) = [r for r in ROWS if r["entry"] == entry and r["task"] == task and r["tier"] == tier]
    return row


def _us_range(rows: list[dict]) -> str:
    """The range of the rows' single-observation compute, rounded to whole µs as the README writes it."""
    values = [r["compute_us_single"] for r in rows]
    return f"{min(values):.0f}-{max(values):.0f} µs"


def _sci(value: float) -> str:
    """``2.8e-4``: one decimal, the exponent without its leading zero."""
    mantissa, exponent = f"{value:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _percent(rate: float) -> str:
    return f"{rate * 100:.0f} %"


def _has(phrase: str, text: str = WORDS, where: str = "the README's headline in words") -> None:
    assert phrase in text, f"{where} should say {phrase!r}"


def _percent_range(rates: list[float]) -> str:
    """The range of crash rates as the README writes it: ``13-80 %``."""
    return f"{_percent(min(rates)).removesuffix(' %')}-{_percent(max(rates))}"


def _cells(count: int) -> str:
    """``no cells``, ``one cell``, ``two cells``, ..."""
    return f"{NUMBER_WORDS[count]} cell{'' if count == 1 else 's'}"


BOUNDED = "distilled mpc robust-bounded (trained on track_random + hover, 5 tiers)"
SMALL_BOUNDED = "distilled mpc robust-bounded-small (trained on track_random + hover, 5 tiers)"


def test_model_based_wins_every_noise_free_window_and_every_last_half_window_but_one():
    decided = [w for w in WINDOWS if w["winner"] != "neither"]
    steady = [w for w in decided if w["window"] == "steady" and w["winner"] != "model-based"]
    assert [(w["task"], w["tier"], w["winner"], w["learned"]["entry"]) for w in steady] == [
        ("track_random", "noisy", "learned", SMALL_BOUNDED)]
    noise_free = [w for w in decided if "noise" not in get_tier(w["tier"]).effects]
    assert noise_free and all(w["winner"] == "model-based" for w in noise_free)
    _has("Model-based control wins every decided window of the noise-free tiers, and every decided last-half window "
         "but one: `track_random` noisy, won by the bounded robust students")


def test_the_learned_wins_are_the_cells_named():
    wins = {(w["task"], w["tier"], w["window"]) for w in WINDOWS if w["winner"] == "learned"}
    paper = {("track_paper", tier, window) for tier in ("noisy", "hard") for window in ("whole", "transient")}
    noisy_random = {("track_random", "noisy", window) for window in ("steady", "final_5s")}
    assert wins == paper | {("hover", "noisy", "final_5s")} | noisy_random
    assert all("noise" in get_tier(tier).effects for _, tier, _ in wins)
    (cell,) = [w for w in WINDOWS if (w["task"], w["tier"], w["window"]) == ("track_paper", "noisy", "whole")]
    assert cell["model_based"]["entry"] == "passivity-integral"
    learned, model = (cell[side]["rms_position_error_whole_iqm"] for side in ("learned", "model_based"))
    _has(f"Learned control wins {NUMBER_WORDS[len(wins)]} cells, all under sensor noise")
    _has(f"({learned:.2f} against the integral loop's {model:.2f} m, noisy, whole episode)")
    (noisy,) = [w for w in WINDOWS if (w["task"], w["tier"], w["window"]) == ("track_random", "noisy", "steady")]
    ours, theirs = (noisy[side]["rms_position_error_steady_iqm"] for side in ("learned", "model_based"))
    _has(f"the last half of `track_random` noisy ({_sci(ours)} against {_sci(theirs)} m, the "
         f"{'MPC' if noisy['model_based']['entry'] == 'mpc' else noisy['model_based']['entry']})")


def test_time_within_1_cm():
    cells = tolerance_headline(BOARD)
    model = sum(c["winner"] == "model-based" for c in cells)
    assert not any(c["winner"] == "learned" for c in cells)
    _has(f"Time within 1 cm of the reference: model-based wins {model} of the {len(cells)} (task, tier) cells, "
         "learned none")


def test_the_compute_ranges():
    mpc = [r for r in ROWS if r["entry"] == "mpc"]
    ms = [r["compute_us_single"] / 1000 for r in mpc]
    _has(f"the MPC takes {min(ms):.1f}-{max(ms):.1f} ms per step and robot")
    _has(f"the integral loop {_us_range([r for r in ROWS if r['entry'] == 'passivity-integral'])}")
    _has(f"the learned MLPs {_us_range([r for r in ROWS if is_learned(r['policy'])])}")


def test_the_mpc_crashes_where_the_integral_loop_does_not():
    crashed = {(r["task"], r["tier"]): (r["crashes"], r["crash_episodes"]) for r in ROWS
               if r["entry"] == "mpc" and r["crashes"]}
    assert crashed == {("track_paper", "noisy"): (4, 20), ("track_paper", "hard"): (5, 20), ("hover", "noisy"): (1, 20)}
    _has("it crashes in 4 and 5 of 20 `track_paper` episodes of the noisy and hard tiers, and in 1 of 20 hover noisy")
    assert not any(r["crashes"] for r in ROWS if r["entry"] == "passivity-integral")
    _has("The integral loop crashes in none.")


def test_the_mpc_students():
    student, mpc = (_row(e, "track_random", "nominal") for e in ("distilled mpc small (trained on nominal)", "mpc"))
    ours, theirs = (r["rms_position_error_steady_iqm"] for r in (student, mpc))
    assert 1 < ours / theirs < 2
    _has(f"come within 2 times of it on `track_random` nominal (last half {_sci(ours)} against {_sci(theirs)} m; "
         f"{student['crashes']} crash in {student['crash_episodes']} episodes), "
         f"at {student['compute_us_single']:.0f} µs per robot")
    for tier in ("noisy", "hard", "model_gap"):
        assert _row("distilled mpc small (trained on nominal)", "track_random", tier)["crashes"] > 0, tier
    _has("They crash under noise and on `model_gap`.")


def test_the_robust_mpc_students():
    entry = "distilled mpc robust (trained on track_random + hover, 5 tiers)"
    rows = [r for r in ROWS if r["entry"] == entry]
    def crashes(task: str) -> str:
        counts = [_row(entry, task, tier) for tier in ("noisy", "hard", "model_gap")]
        assert all(r["crash_episodes"] == 100 for r in counts)
        return f"{counts[0]['crashes']}, {counts[1]['crashes']} and {counts[2]['crashes']} of 100"

    _has(f"crash in {crashes('track_random')} `track_random` noisy, hard and `model_gap` episodes and in "
         f"{crashes('hover')} hover ones, at {_us_range(rows)} per robot; they win no cell")
    assert not any(w["learned"]["entry"] == entry and w["winner"] == "learned" for w in WINDOWS)


def test_the_bounded_robust_students():
    entry = BOUNDED
    rows = [r for r in ROWS if r["entry"] == entry]
    by_task = {task: [r for r in rows if r["task"] == task] for task in ("track_random", "hover", "track_paper")}
    assert all(r["crash_episodes"] == 100 for r in by_task["track_random"] + by_task["hover"])
    assert len(by_task["track_random"]) == len(by_task["hover"]) == 6
    assert not any(r["crashes"] for r in by_task["track_random"])
    (hover,) = [r for r in by_task["hover"] if r["crashes"]]
    assert _row("mpc", "hover", hover["tier"])["crashes"] == 0
    paper = [r["crash_rate"] for r in by_task["track_paper"]]
    wins = [w for w in WINDOWS if w["learned"]["entry"] == entry and w["winner"] == "learned"]
    _has(f"crash in none of the 600 `track_random` episodes and in {hover['crashes']} of the 600 hover ones (all "
         f"`{hover['tier']}`, where the MPC crashes in none), at {_us_range(rows)} per robot")
    _has(f"in {_percent_range(paper)} of the `track_paper` episodes")
    _has(f"they win {_cells(len(wins))}")


def test_the_small_bounded_robust_students():
    rows = [r for r in ROWS if r["entry"] == SMALL_BOUNDED]
    def crashes(task: str) -> int:
        counted = [r for r in rows if r["task"] == task]
        assert len(counted) == 6 and all(r["crash_episodes"] == 100 for r in counted)
        return sum(r["crashes"] for r in counted)

    paper = [r["crash_rate"] for r in rows if r["task"] == "track_paper"]
    wins = [w for w in WINDOWS if w["learned"]["entry"] == SMALL_BOUNDED and w["winner"] == "learned"]
    us = json.loads((LAYOUT.root / "benchmarks" / "per_robot_compute.json").read_text())
    _has(f"At 2 x 64 the same students crash in {crashes('track_random')} of the 600 `track_random` episodes and in "
         f"{crashes('hover')} of the 600 hover ones, in {_percent_range(paper)} of the `track_paper` ones, at "
         f"{_us_range(rows)} per robot ({us['us']['student-small-lean']['median']:.0f} µs by "
         f"`benchmarks/per_robot_compute.py`, {us['small_student_over_integral']:.1f} times the integral loop, "
         f"where the 2 x 256 ones take {us['us']['student-lean']['median']:.0f} µs; with the integral loop they "
         f"correct, which the robot runs too, {us['small_student_with_loop_over_integral']:.1f} times); they win "
         f"{_cells(len(wins))}")


def test_the_fine_tuned_students():
    finetuned = _row("PPO student-finetune (trained on nominal)", "track_random", "nominal")
    mpc = _row("mpc", "track_random", "nominal")
    assert verdict(mpc, finetuned, "rms_position_error_whole")[0] == "neither"
    _has("students tie the MPC over the whole of `track_random` nominal "
         f"({finetuned['rms_position_error_whole_iqm']:.3f} against {mpc['rms_position_error_whole_iqm']:.3f} m)")
    hard = _row("PPO student-finetune (trained on hard)", "track_random", "hard")
    students = [r["crash_rate"] for r in ROWS
                if r["entry"].startswith("distilled") and r["task"] == "track_random" and r["tier"] == "hard"]
    _has(f"Fine-tuned on the hard tier they crash in {_percent(hard['crash_rate'])} of its episodes (the students in "
         f"{min(students) * 100:.0f}-{_percent(max(students))})")
    gap = _row("PPO student-history-finetune (trained on model_gap)", "track_random", "model_gap")
    assert all(_row(e, "track_random", "model_gap")["crashes"] == 0 for e in ("mpc", "passivity-integral"))
    _has(f"fine-tuned on `model_gap`, crash in {_percent(gap['crash_rate'])} of its episodes "
         "(the MPC and the integral loop in none)")


@pytest.mark.parametrize("entry, finished", [
    ("PPO actuators-curriculum (trained on nominal)", "3 with a curriculum over the paper's own start"),
    ("PPO actuators-wide (trained on track_random, nominal)", "1 with wide starts"),
    ("PPO-actuators (trained on nominal)", "none without either"),
    ("PPO-actuators (trained on track_random, nominal)", "none without either"),
])
def test_ppo_on_raw_actuators_rarely_finishes_the_papers_reference(entry, finished):
    row = _row(entry, "track_paper", "nominal")
    count = row["crash_episodes"] - row["crashes"]
    assert finished.startswith("none" if count == 0 else str(count))
    _has(f"of the {row['crash_episodes']} nominal seeds")
    _has(finished)


def test_the_zero_residual_cell_against_the_plain_residual():
    """docs/baselines.md, "Frame stacking and env options": PPO residual-zero against PPO-residual, both trained
    on track_random nominal."""
    zero, plain = "PPO residual-zero (trained on nominal)", "PPO-residual (trained on nominal)"

    def _says(phrase):
        _has(phrase, BASELINES_PAGE, "docs/baselines.md")

    behind = total = 0
    for zero_entry, plain_entry in ((zero, plain), ("PPO residual-zero (trained on track_random, nominal)",
                                                    "PPO-residual (trained on track_random, nominal)")):
        for r in (r for r in ROWS if r["entry"] == zero_entry):
            other = _row(plain_entry, r["task"], r["tier"])
            for _, metric, _ in WINDOW_METRICS:
                ours, theirs = r[f"{metric}_iqm"], other[f"{metric}_iqm"]
                total += 1
                behind += theirs is not None and (ours is None or ours > theirs)  # a crashed window: None
    assert behind > total / 2, (behind, total)
    _says("It loses to the plain residual in most cells")
    a, b = _row(zero, "track_random", "nominal"), _row(plain, "track_random", "nominal")
    _says(f"on `track_random` nominal its whole-episode IQM is {a['rms_position_error_whole_iqm']:.3f} m against "
          f"{b['rms_position_error_whole_iqm']:.3f} m and its last half {a['rms_position_error_steady_iqm']:.3f} m "
          f"against {b['rms_position_error_steady_iqm']:.3f} m")
    a, b = _row(zero, "track_random", "mismatch"), _row(plain, "track_random", "mismatch")
    _says(f"under mismatch its last half is {a['rms_position_error_steady_iqm']:.3f} m against "
          f"{b['rms_position_error_steady_iqm']:.3f} m")
    noisy, hard = (_row(zero, "track_random", tier) for tier in ("noisy", "hard"))
    assert _row(plain, "track_random", "noisy")["crashes"] == 0
    _says(f"under sensor noise it crashes in {_percent(noisy['crash_rate'])} of the `track_random` episodes (the plain "
          f"residual in none), and in {_percent(hard['crash_rate'])} on the hard tier")


def test_the_mpc_paragraph_of_the_controller_page():
    """docs/control.md, "Nonlinear MPC": the figures after the table, from the table's JSON
    (benchmarks/mpc_quality.json) and the leaderboard's rows."""
    episodes = json.loads((LAYOUT.root / "benchmarks" / "mpc_quality.json").read_text())
    run = {(r["tier"], r["policy"]): r for r in episodes}
    page = " ".join(LAYOUT.doc("control.md").read_text().split())

    def _says(phrase):
        _has(phrase, page, "docs/control.md")

    for tier in ("nominal", "wind"):
        mpc, bounded = run[(tier, "mpc")], run[(tier, "passivity-bounded")]
        assert 0.4 < mpc["rms_0_10s"] / bounded["rms_0_10s"] < 0.6, tier  # "about half"
        assert mpc["solver"]["fallbacks"] == 0 and mpc["solver"]["solves"] == 4000, tier
    _says("with no fallback in 4,000 solves")
    nominal, wind, noisy = (run[(tier, "mpc")] for tier in ("nominal", "wind", "noisy"))
    b_nominal, b_wind, b_noisy = (run[(tier, "passivity-bounded")] for tier in ("nominal", "wind", "noisy"))
    _says(f"20–40 s RMS {_sci(nominal['rms_20_40s'])} m against {_sci(b_nominal['rms_20_40s'])} m on nominal, "
          f"{_sci(wind['rms_20_40s'])} m against {b_wind['rms_20_40s']:.2g} m under wind")
    assert not noisy["crashed"]
    _says(f"this episode finishes at {noisy['rms_20_40s']:.2g} m over 20–40 s (the bounded loop: "
          f"{b_noisy['rms_20_40s']:.2g} m)")
    crashes = _row("mpc", "track_paper", "noisy")
    assert _row("passivity-bounded", "track_paper", "noisy")["crashes"] == 0
    _says(f"but {crashes['crashes']} of the leaderboard's {crashes['crash_episodes']} `track_paper` noisy episodes "
          "crash (the bounded loop: none)")
    _says(f"on nominal the bounded loop's largest error over the last 5 s is smaller "
          f"({_sci(b_nominal['max_final_5s'])} m against {_sci(nominal['max_final_5s'])} m")
    solver = [r["solver"] for r in episodes if r["policy"] == "mpc"]

    def _span(key, digits):
        values = [s[key] for s in solver]
        return f"{min(values):.{digits}f}–{max(values):.{digits}f} ms"

    _says(f"The median step ({_span('solve_ms_median', 1)} here")
    _says(f"p99 ({_span('solve_ms_p99', 1)}) and every solve here (max {_span('solve_ms_max', 0)})")
    assert all(_row("mpc", task, "model_gap")["crashes"] == 0 for task in BOARD["meta"]["tasks"])
    _says("(none on `model_gap`)")


def test_the_per_robot_compute_ratios_of_the_guide():
    """docs/baselines.md, "Per-robot compute": the ratios of benchmarks/per_robot_compute.json."""
    data = json.loads((LAYOUT.root / "benchmarks" / "per_robot_compute.json").read_text())
    us = {name: row["median"] for name, row in data["us"].items()}
    _has(f"the lean path of a 2 x 64 MLP costs {data['lean_over_integral']:.1f} times what the integral passivity "
         f"loop costs, SB3's `predict` calls {data['torch_over_lean']:.0f} times the lean path and "
         f"SB3's `model.predict` {us['learned-sb3'] / us['learned-lean']:.0f} times;", BASELINES_PAGE,
         "docs/baselines.md")
    _has(f"a residual on the integral loop) {data['student_over_integral']:.1f} times the integral loop, and at "
         f"2 x 64 {data['small_student_over_integral']:.1f} times (the 2 x 64 MLP above, on one observation without "
         f"a frame stack, {data['lean_over_integral']:.1f} times)", BASELINES_PAGE, "docs/baselines.md")
    with_loop = data["small_student_with_loop_over_integral"]
    _has(f"the small student with its integral loop costs {with_loop:.1f} times the loop alone, above the compute "
         f"goal of 2 times", BASELINES_PAGE, "docs/baselines.md")
    assert with_loop > 2.0  # what "above" says
    loops = [r for r in ROWS if r["policy"].startswith("passivity")]
    _has(f"cost is that passivity loop's own row ({_us_range(loops)} on this board)", BASELINES_PAGE,
         "docs/baselines.md")


def test_the_pictures_policy_of_the_guide():
    """docs/baselines.md, "Pictures": the learned policy the figures script selects from the committed leaderboard
    (its cells: ``results/leaderboard.json``), its seed and errors."""
    from softpvtol_gym.baselines.figures.tracking import select_learned
    from tests.conftest import LEADERBOARD_JSON

    chosen = select_learned(json.loads(LEADERBOARD_JSON.read_text()))
    assert chosen.entry == "PPO-residual (trained on track_random, hard)"
    bounded = _row("passivity-bounded", "track_paper", "nominal")["rms_position_error_iqm"]
    _has(f"PPO-residual trained on `track_random` in the hard tier (it never sees `track_paper`), seed {chosen.seed}, "
         f"{chosen.seed_rms:.3f} m (entry IQM {chosen.entry_iqm:.3f} m against {bounded:.3f} m for "
         "`passivity-bounded`)",
         BASELINES_PAGE, "docs/baselines.md")
    assert headline(BOARD)["policy"] == "PPO residual-precise trained on track_random (hard tier)"
    _has("It is not the leaderboard's headline policy (`PPO residual-precise` trained on `track_random`'s hard tier",
         BASELINES_PAGE, "docs/baselines.md")


def test_what_the_integral_sweep_shows():
    """docs/control.md, "Integral action": the paragraph under the sweep's table, from the table's JSON
    (benchmarks/integral_sweep.json)."""
    from scipy.stats import fisher_exact

    sweep = json.loads((LAYOUT.root / "benchmarks" / "integral_sweep.json").read_text())
    bounded, raised, chosen = (sweep["variants"][name] for name in (
        "bounded (no integral)", "raised gains, no integral (error clip 0.5 m)", "**integral** (the loop's settings)"))
    page = " ".join(LAYOUT.doc("control.md").read_text().split())
    episodes = sweep["episodes"]

    def _says(phrase):
        _has(phrase, page, "docs/control.md")

    def steady(variant, cell):
        return variant[cell]["steady"]

    _says(f"Raised gains alone (third row) remove most of the offsets but keep {steady(raised, 'hover/mismatch'):.2f} "
          "m under mismatch")
    hover = steady(chosen, "hover/mismatch")
    _says(f"falls to {hover:.3f} m on hover ({hover / steady(bounded, 'hover/mismatch'):.1%} of the bounded loop's "
          f"{steady(bounded, 'hover/mismatch'):.2f} m), {steady(chosen, 'track_paper/mismatch'):.2g} m on "
          f"`track_paper` and {steady(chosen, 'track_random/mismatch'):.2g} m on `track_random`".replace("%", " %"))
    wind = steady(chosen, "hover/wind")
    _says(f"under wind to {wind:.2f} m on hover ({wind / steady(bounded, 'hover/wind'):.0%} of "
          f"{steady(bounded, 'hover/wind'):.2f} m".replace("%", " %"))

    def crashes(variant):
        return {cell: round(v["crash_rate"] * episodes) for cell, v in variant.items() if v["crash_rate"]}

    total = len(chosen) * episodes
    assert crashes(chosen) == {"hover/noisy": 1} and crashes(raised) == {}
    assert sorted(crashes(bounded)) == sorted(f"{task}/{tier}" for task in ("hover", "track_paper", "track_random")
                                              for tier in ("mismatch", "hard"))
    _says(f"It crashed in 1 of the {total} episodes (hover noisy), the raised gains alone in none, the bounded loop "
          f"in {sum(crashes(bounded).values())} (one in each mismatch and hard cell)")
    p = fisher_exact([[1, total - 1], [0, total]], alternative="greater").pvalue
    _says(f"1 of {total} against 0 of {total} is no evidence of a difference (one-sided Fisher exact test, "
          f"p = {p:.1f})")
    ratios = [steady(raised, f"{task}/mismatch") / steady(chosen, f"{task}/mismatch")
              for task in ("hover", "track_paper", "track_random")]
    _says(f"the integral row is {min(ratios):.0f} to {max(ratios):.0f} times lower under mismatch")
    _says(f"on hover nominal the integral's slow mode leaves {steady(chosen, 'hover/nominal'):.3f} m over the last "
          f"half, where the raised gains alone reach {_sci(steady(raised, 'hover/nominal'))} m")
    both = [steady(v, "track_paper/nominal") for v in (raised, chosen)]
    assert all(f"{b:.0e}" == "2e-05" for b in both), both
    _says("on `track_paper` nominal both reach 2e-5 m")
    assert chosen["track_paper/model_gap"]["crash_rate"] == 0
    assert sweep["variants"]["integral, error clip 1 m"]["track_paper/model_gap"]["crash_rate"] == 1
    _says("A looser law-error clip (1 m) gives a faster `track_paper` transient but folds the arms in every "
          "`model_gap` episode")


@pytest.mark.slow  # two 40-s closed loops: a few seconds
def test_the_extended_loops_figures(tmp_path, capsys):
    """docs/control.md, "Exact tracking": the figures around the extended loop's tables, from their JSON
    (benchmarks/extended_loop.json, results/paper_reproduction/metrics.json) and the two commands the page names."""
    from softpvtol_gym.baselines.cli import run_command
    from softpvtol_gym.control.extended import simulate_extended_loop

    data = json.loads((LAYOUT.root / "benchmarks" / "extended_loop.json").read_text())
    paper = json.loads((LAYOUT.results / "paper_reproduction" / "metrics.json").read_text())
    bounded_step = paper["steady_state"]["loops"]["bounded"]["step"]["0.01"]["worst_max_abs_xz"]
    worst = {name: cell["worst_max_abs_xz"] for name, cell in data["simulation"]["cells"].items()}
    page = " ".join(LAYOUT.doc("control.md").read_text().split())

    def _says(phrase):
        _has(phrase, page, "docs/control.md")

    _says(f"it falls {worst['stage 0.01'] / worst['stage 0.005']:.0f}× when dt halves (dt⁴; "
          f"{worst['stage 0.005'] / worst['stage 0.002']:.0f}× from 0.005 to 0.002 s")
    _says(f"about {bounded_step / worst['step 0.01']:.0f}× below the bounded loop's at dt = 0.01 s")
    env = data["env"]
    assert 3.5 < env["bounded"]["rms_position_30_40s"] / env["extended"]["rms_position_30_40s"] < 4.5
    _says("Over 30–40 s the extended policy tracks four times closer than the bounded one and never saturates")
    assert env["extended"]["saturated_step_share"] == 0.0
    cell = data["simulation"]["cells"]["stage 0.01"]
    _says(f"the loop asks for at most {cell['max_thrust_per_rotor_N']:.1f} N per rotor")
    _says(f"and {cell['max_abs_arm_torque_Nm']:.1f} N m of arm torque")

    run = simulate_extended_loop(t_final=40, hold="step", held_command="start")
    window = (run["t"] >= 30.0) & (run["t"] <= 40.0)
    held_at_start = float(np.abs(run["q"][window][:, :2] - run["q_ref"][window][:, :2]).max())
    assert 2.5 < held_at_start / bounded_step < 3.5  # "three times the bounded loop's figure in the table"
    _says(f"error is O(dt): {_sci(held_at_start)} m at dt = 0.01 s over 30–40 s from the paper's q(0)")

    out = tmp_path / "extended.json"
    code = run_command("evaluate", ["--policy", "passivity", "--controller-loop", "extended", "--task", "track_paper",
                                    "--episodes", "1", "--json", str(out)])
    assert code in (0, None), capsys.readouterr().err
    (episode,) = json.loads(out.read_text())["episodes"]
    bounded = json.loads((LAYOUT.results / "passivity_metrics.json").read_text())["cells"]["track_paper/nominal"]
    _says(f"gives an RMS position error of {episode['rms_position_error']:.2f} m (seed 1,000,000; the bounded loop's "
          f"mean over {bounded['episodes']} episodes in the table below is {bounded['rms_position_error_m']:.2f} m)")


def test_the_algebraic_loops_passes():
    """docs/control.md, "Closed loops": the algebraic loop's passes on the paper's case, from
    results/paper_reproduction/metrics.json."""
    loops = json.loads((LAYOUT.results / "paper_reproduction" / "metrics.json").read_text())["loops"]
    solved = {name: m["algebraic_loop"] for name, m in loops.items() if m.get("algebraic_loop")}
    assert max(s["residual_max_rad"] for s in solved.values()) <= 1e-10
    means = {f"{s['passes_mean']:.1f}" for s in solved.values()}
    worst = max(solved, key=lambda name: solved[name]["passes_max"])
    assert means == {"2.1"} and worst == "improved_zero_order_hold"
    _has(f"every step is solved to ≤ 1e-10 rad with 2.1 passes on average (at most {solved[worst]['passes_max']}, "
         "in the first 0.1 s of the improved loop under a zero-order hold",
         " ".join(LAYOUT.doc("control.md").read_text().split()), "docs/control.md")


@pytest.mark.slow  # 12 episodes of 40 s: seconds
def test_the_pictures_episodes_of_the_guide():
    """docs/baselines.md, "Pictures": what the figures script prints of the episodes it draws, flown again."""
    from softpvtol_gym import PassivityPolicy, SoftPVTOLVectorEnv
    from softpvtol_gym.baselines.figures.tracking import (
        TASK,
        episode_summary,
        load_learned,
        reference_env_kwargs,
        run_trajectory,
        select_learned,
    )
    from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE, load_spec
    from tests.conftest import LEADERBOARD_JSON

    chosen = select_learned(json.loads(LEADERBOARD_JSON.read_text()), base=LAYOUT.root)
    policy, config, _, _ = load_learned(chosen.checkpoint)
    kwargs = reference_env_kwargs(SPEC_FILE)
    analytic = PassivityPolicy.from_env(SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task=TASK, **kwargs))
    bounded, learned = {}, {}
    for tier in load_spec(SPEC_FILE)["evaluation"]["tiers"]:
        bounded[tier] = episode_summary(run_trajectory(analytic, "actuators", TASK, tier, 1_000_000, None, kwargs))
        learned[tier] = episode_summary(run_trajectory(policy, config.action_mode, TASK, tier, 1_000_000, None,
                                                       config.eval_env_kwargs()))
    assert [t for t, v in learned.items() if v["crashed"]] == ["model_gap"]
    assert not any(v["crashed"] for v in bounded.values())
    others = [t for t in learned if t != "model_gap"]

    def span(values, digits):
        return f"{min(values):.{digits}f}-{max(values):.{digits}f}"

    def _says(phrase):
        _has(phrase, BASELINES_PAGE, "docs/baselines.md")

    _says(f"the learned policy's `model_gap` episode, at {learned['model_gap']['seconds']:.2f} s")
    _says(f"first below 0.2 m after {span([learned[t]['first_close'] for t in others], 1)} s in the other tiers, "
          f"`passivity-bounded`'s after {span([v['first_close'] for v in bounded.values()], 1)} s")
    assert all(learned[t]["first_close"] < bounded[t]["first_close"] for t in others)
    _says(f"After 10 s the learned policy stays within {span([learned[t]['max_settled'] for t in others], 2)} m")
    _says(f"(within {bounded['nominal']['max_settled']:.2f} m after 10 s)")
    _says(f"under wind and in the hard tier stays within "
          f"{span([bounded[t]['max_settled'] for t in ('wind', 'hard')], 2)} m")
