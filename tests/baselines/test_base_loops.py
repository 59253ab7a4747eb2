"""The leaderboard shows each residual entry beside its own base loop and marks the windows where it is worse."""

from __future__ import annotations

import json

import pytest

from softpvtol_gym.baselines.leaderboard.base_loops import WORSE, base_loop, base_loop_comparisons, worse, worse_windows
from softpvtol_gym.baselines.leaderboard.render import base_loop_markdown, render_markdown
from softpvtol_gym.baselines.leaderboard.stats import WINDOWS
from tests.conftest import LEADERBOARD_JSON


def _row(entry: str, value: float | None, mode: str = "actuators", recipe: str | None = None, **windows) -> dict:
    row = {"task": "track_random", "tier": "nominal", "entry": entry, "action_mode": mode, "recipe": recipe}
    for _, metric, _ in WINDOWS:
        row[f"{metric}_iqm"] = windows.get(metric, value)
    return row


def test_the_base_loop_is_the_recipes_or_the_envs_default():
    assert base_loop({"action_mode": "residual", "recipe": None}) == "bounded"
    assert base_loop({"action_mode": "residual", "recipe": "residual-tracking"}) == "integral"
    assert base_loop({"action_mode": "actuators", "recipe": None}) is None


@pytest.mark.parametrize("value, base, expected", [
    (0.2, 0.1, True), (0.1, 0.2, False), (0.1, 0.1, False),
    (None, 0.1, True),  # a crashed window is worse than any value
    (0.1, None, False), (None, None, False),
])
def test_worse_counts_a_crash_as_worse_than_any_value(value, base, expected):
    assert worse(value, base) is expected


def test_each_residual_is_compared_with_its_own_base_loop_per_window():
    steady = "rms_position_error_steady"
    data = {"aggregates": [
        _row("passivity-bounded", 0.10),
        _row("passivity-integral", 0.05, **{steady: 1e-4}),
        _row("PPO-residual", 0.08, mode="residual", **{steady: 0.2}),  # over the bounded loop
        _row("PPO residual-tracking", 0.06, mode="residual", recipe="residual-tracking",
             **{steady: None}),  # over the integral loop
        _row("PPO-actuators", 0.5),  # not a residual: no base loop
    ]}
    rows = {r["entry"]: r for r in base_loop_comparisons(data)}
    assert set(rows) == {"PPO-residual", "PPO residual-tracking"}
    assert rows["PPO-residual"]["base"] == "passivity-bounded"
    assert rows["PPO-residual"]["worse"] == {"whole": False, "transient": False, "steady": True, "final_5s": False}
    assert rows["PPO residual-tracking"]["base"] == "passivity-integral"
    assert rows["PPO residual-tracking"]["worse"] == {"whole": True, "transient": True, "steady": True,
                                                      "final_5s": True}
    assert worse_windows(data)[("track_random", "nominal", "PPO-residual")] == {steady}
    text = "\n".join(base_loop_markdown(data))
    assert "in 5 of 8 (task, tier, entry, window) cells" in text and "in at least one window in 2 of 2" in text
    assert f"| PPO-residual | passivity-bounded | 0.080 vs 0.100 | 0.080 vs 0.100 | 0.200 {WORSE} vs 0.100 |" in text
    assert f"crash {WORSE} vs 1.0e-04" in text


def test_a_residual_without_its_base_loop_on_the_board_is_left_out():
    data = {"aggregates": [_row("PPO-residual", 0.08, mode="residual")]}
    assert base_loop_comparisons(data) == [] and base_loop_markdown(data) == []


def test_the_committed_page_marks_residuals_worse_than_their_base():
    data = json.loads(LEADERBOARD_JSON.read_text())
    rows = base_loop_comparisons(data)
    residual = {(r["task"], r["tier"], r["entry"]) for r in data["aggregates"] if r["action_mode"] == "residual"}
    assert {(r["task"], r["tier"], r["entry"]) for r in rows} == residual  # every residual beside its base
    page = render_markdown(data)
    assert "## Residual entries beside their base loops" in page
    cells = sum(sum(r["worse"].values()) for r in rows)
    assert cells > 0 and page.count(f" {WORSE} ") == 2 * cells  # in the base-loop table and in the task's table
