"""baselines/tracking_figures.py (the pictures): the choice of the learned policy from a leaderboard
JSON, short runs of each picture into tmp_path, bad input exits 2 before any work, and the committed
pictures exist, are what they claim to be and are shown in the README."""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pytest  # noqa: E402
from PIL import Image  # noqa: E402

from softpvtol_gym.baselines.commands.figures import main
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.figures.tracking import select_learned
from tests.conftest import LAYOUT, RUNS_DIR

ROOT = Path(__file__).resolve().parents[2]
CELL = "results/leaderboard_runs/ppo_residual_track_random_nominal"
CHECKPOINT = ROOT / CELL / "seed_0"
#: the committed pictures (python baselines/tracking_figures.py)
TRACKING_PNG = LAYOUT.results / "tracking" / "track_paper.png"
CURVES_PNG = LAYOUT.results / "tracking" / "learning_curves.png"
GIF = LAYOUT.doc("best_policy_track_paper.gif")


def _cell(entry, seed, rms, task="track_paper", tier="nominal", checkpoint=None, **extra):
    return {"entry": entry, "policy": "ppo" if checkpoint else entry, "task": task, "tier": tier, "seed": seed,
            "checkpoint": checkpoint, **extra,
            "episodes": [{"rms_position_error": rms - 0.1}, {"rms_position_error": rms + 0.1}]}


def _row(entry, iqm, task="track_paper", tier="nominal", learned=True, **extra):
    return {"entry": entry, "policy": "ppo" if learned else entry, "task": task, "tier": tier,
            "rms_position_error_iqm": iqm, **extra}


def synthetic_leaderboard(seed_rms=(3.0, 1.0, 5.0, 2.0, 4.0), checkpoint=f"{CELL}/seed_{{seed}}/model.safetensors"):
    """passivity lower than any learned entry (it must not be chosen); 'B' the best learned entry on
    track_paper nominal; 'A' better than 'B' elsewhere only."""
    cells = [_cell("passivity-bounded", 0, 0.5)]
    for seed, rms in enumerate(seed_rms):
        cells.append(_cell("B", seed, rms, checkpoint=checkpoint.format(seed=seed)))
        cells.append(_cell("A", seed, 9.0, checkpoint=f"a/seed_{seed}/model.safetensors"))
        cells.append(_cell("B", seed, 0.1, tier="hard", checkpoint=f"b/hard/seed_{seed}/model.safetensors"))
    rows = [_row("passivity-bounded", 0.5, learned=False), _row("A", 8.0), _row("B", 2.5), _row("A", 0.1, tier="hard"),
            _row("A", 0.1, task="hover")]
    return {"meta": {}, "aggregates": rows, "cells": cells}


# ------------------------------------------------------------------------------- the selection
@pytest.mark.parametrize("seed_rms, median_seed", [
    ((3.0, 1.0, 5.0, 2.0, 4.0), 0),   # sorted: 1 (s1), 2 (s3), 3 (s0), 4 (s4), 5 (s2) -> s0
    ((0.2, 0.9, 0.5), 2),
    ((0.4, 0.3, 0.2, 0.1), 2),        # even count: the lower middle one (0.2)
    ((7.0,), 0),
])
def test_selection_takes_the_best_learned_entry_and_its_median_seed(seed_rms, median_seed):
    chosen = select_learned(synthetic_leaderboard(seed_rms), base=ROOT)
    assert chosen.entry == "B" and chosen.entry_iqm == 2.5
    assert chosen.seed == median_seed and chosen.seeds == len(seed_rms)
    assert chosen.seed_rms == pytest.approx(seed_rms[median_seed])
    assert chosen.checkpoint == ROOT / CELL / f"seed_{median_seed}" / "model.safetensors"
    assert "median" in chosen.caption() and f"seed {median_seed}" in chosen.caption()


def test_selection_takes_cross_task_rows_and_matches_train_task():
    data = synthetic_leaderboard()
    # an entry trained on track_random, evaluated on track_paper (cells and rows with train_task): better than B
    for seed, rms in enumerate((0.9, 0.7, 0.8)):
        data["cells"].append(_cell("C", seed, rms, checkpoint=f"c/seed_{seed}", train_task="track_random"))
        data["cells"].append(_cell("C", seed, 9.0, checkpoint=f"c2/seed_{seed}", train_task="track_paper"))
    data["aggregates"].append(_row("C", 0.8, train_task="track_random"))
    chosen = select_learned(data, base=ROOT)
    assert (chosen.entry, chosen.seed, chosen.seeds) == ("C", 2, 3)
    assert chosen.checkpoint == ROOT / "c" / "seed_2"


@pytest.mark.parametrize("change, match", [
    (lambda d: d["aggregates"].clear(), "no learned entry evaluated on track_paper nominal"),
    (lambda d: [c.update(seed=0) for c in d["cells"] if c["entry"] == "B"], "not one checkpoint per seed"),
    (lambda d: d["cells"][1].pop("checkpoint"), "not one checkpoint per seed"),
    (lambda d: d["aggregates"][2].pop("rms_position_error_iqm"), "not a usable leaderboard JSON"),
    (lambda d: d.pop("cells"), "is not a leaderboard JSON"),
])
def test_selection_errors_name_the_problem(change, match):
    data = copy.deepcopy(synthetic_leaderboard())
    change(data)
    with pytest.raises(ConfigError, match=match):
        select_learned(data)


# ----------------------------------------------------------------------------- the pictures, short
def _png(path: Path) -> tuple:
    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


@pytest.mark.parametrize("source", ["checkpoint", "leaderboard"])
def test_tracking_plot_and_gif_of_a_short_episode(tmp_path, capsys, source):
    png, gif = tmp_path / "out" / "t.png", tmp_path / "b.gif"
    argv = ["--only", "tracking", "--only", "gif", "--tiers", "nominal", "--seconds", "0.3", "--gif-seconds", "0.3",
            "--gif-fps", "10", "--gif-scale", "0.2", "--tracking-out", str(png), "--gif-out", str(gif)]
    if source == "checkpoint":
        argv += ["--checkpoint", str(CHECKPOINT)]
    else:
        (tmp_path / "lb.json").write_text(json.dumps(synthetic_leaderboard()))
        argv += ["--leaderboard", str(tmp_path / "lb.json")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "nominal, passivity-bounded: RMS" in out
    assert "nominal, PPO-residual (trained on track_random nominal): RMS" in out
    assert ("given by --checkpoint" if source == "checkpoint" else "B, seed 0: the median of its 5 seeds") in out
    width, height = _png(png)
    assert width > 300 and height > 300
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.size == (120, 90) and im.n_frames == 3  # 0.3 s at 10 frames/s


@pytest.mark.parametrize("reference", ["leaderboard", "heldout"])
def test_learning_curves_from_runs(tmp_path, capsys, reference):
    """Two timed runs of a cell (drawn against seconds) and an untimed one of another (against steps)."""
    base = (CHECKPOINT / "config.yaml").read_text()
    runs = [("ppo_residual_hover_nominal", 0, True), ("ppo_residual_hover_nominal", 1, True)]
    if reference == "leaderboard":  # (the held-out reference of a track_paper run would take 40 s episodes)
        runs.append(("ppo_virtual_track_paper_nominal", 0, False))
    for cell, seed, timed in runs:
        run = tmp_path / "runs" / cell / f"seed_{seed}"
        run.mkdir(parents=True)
        task = "hover" if "hover" in cell else "track_paper"
        mode = cell.split("_")[1]
        config = (base.replace("task: track_random", f"task: {task}").replace("seed: 0", f"seed: {seed}")
                  .replace("eval_episodes: 5", "eval_episodes: 1")
                  .replace("action_mode: residual", f"action_mode: {mode}"))
        (run / "config.yaml").write_text(config)
        history = [{"step": s, "mean_rms_position_error": 1.0 / (1 + s), **({"train_seconds": s / 10} if timed else {})}
                   for s in (0, 10, 20)]
        (run / "evaluations.json").write_text(json.dumps(history))
    lb = tmp_path / "lb.json"
    reference_row = _row("passivity-bounded", 0.4, task="hover", learned=False)
    lb.write_text(json.dumps({"aggregates": [reference_row], "cells": []}))
    out = tmp_path / "c.png"
    argv = ["--only", "curves", "--runs", str(tmp_path / "runs"), "--curves-out", str(out), "--curve-reference",
            reference, "--leaderboard", str(lb)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "runs; passivity-bounded levels: hover/nominal" in text
    if reference == "leaderboard":
        assert "hover/nominal 0.400 m" in text and "(3 runs" in text
    _png(out)


@pytest.mark.parametrize("argv, match", [
    (["--only", "pictures"], "invalid choice"),
    (["--tracking-out", "{tmp}/t.txt"], "--tracking-out must name a .png file"),
    (["--tracking-out", "{tmp}"], "is a directory"),
    (["--gif-out", "{tmp}/g.png"], "--gif-out must name a .gif file"),
    (["--gif-fps", "30"], "--gif-fps must divide 100"),
    (["--seconds", "0"], "--seconds"),
    (["--tiers", "windy"], "invalid choice"),
    (["--checkpoint", "{tmp}/none"], "does not exist"),
    (["--leaderboard", "{tmp}/none.json"], "no leaderboard JSON at"),
    (["--leaderboard", "{tmp}/bad.json"], "is not valid JSON"),
    (["--leaderboard", "{tmp}/empty.json"], "no learned entry evaluated on track_paper nominal"),
    (["--runs", "{tmp}/none"], "is not a directory"),
    (["--runs", "{tmp}/runs"], "no learned run with an evaluations.json"),
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, argv, match):
    (tmp_path / "bad.json").write_text('{"aggregates": [')
    (tmp_path / "empty.json").write_text('{"aggregates": [], "cells": []}')
    (tmp_path / "runs").mkdir()
    outs = {"--tracking-out": str(tmp_path / "o" / "t.png"), "--curves-out": str(tmp_path / "o" / "c.png"),
            "--gif-out": str(tmp_path / "o" / "g.gif")}
    base = {**outs, "--runs": str(RUNS_DIR)}
    for k, v in zip(argv[::2], argv[1::2]):
        base[k] = v.replace("{tmp}", str(tmp_path))
    with pytest.raises(SystemExit) as exc:
        main([x for kv in base.items() for x in kv], layout=LAYOUT)  # as python baselines/tracking_figures.py
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("tracking_figures.py: error:") and match in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


# -------------------------------------------------------------------------- the committed pictures
@pytest.mark.parametrize("path", [TRACKING_PNG, CURVES_PNG, GIF])
def test_committed_pictures_exist_and_are_in_the_docs(path):
    """docs/baselines.md shows the three pictures (links relative to docs/), the README the GIF."""
    page = (ROOT / "docs" / "baselines.md").read_text()
    relative = os.path.relpath(path, ROOT / "docs").replace(os.sep, "/")
    assert f"]({relative})" in page, f"docs/baselines.md does not show {relative}"
    if path == GIF:
        assert f"]({path.relative_to(ROOT).as_posix()})" in (ROOT / "README.md").read_text()
    if path.suffix == ".gif":
        assert path.stat().st_size < 1.5e6
        with Image.open(path) as im:
            assert im.format == "GIF" and im.n_frames > 10
    else:
        _png(path)
    assert "python baselines/tracking_figures.py" in page


class FullDown:
    """A policy that commands every actuator to its lower limit: the episode ends early (a crash)."""

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        import numpy as np

        return -np.ones((len(observation), 4), np.float32), None


def test_a_crash_ends_the_trajectory_and_is_drawn(tmp_path):
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.figures.tracking import reference_env_kwargs, run_trajectory, tracking_figure
    from softpvtol_gym.baselines.leaderboard.jobs import SPEC_FILE

    run = run_trajectory(FullDown(), "actuators", "track_paper", "nominal", 1_000_000, 2.0, {})
    assert run["crashed"] and run["reason"] and run["t"][-1] < 1.0 and len(run["t"]) == len(run["err"])
    learned = (FullDown(), RunConfig(action_mode="actuators", task="track_paper"), "full down", "a test policy")
    out = tmp_path / "crash.png"
    passivity = reference_env_kwargs(SPEC_FILE)
    result = tracking_figure(["nominal"], 1_000_000, 1.0, learned, passivity, out)
    assert result["nominal"]["full down"]["crashed"] and result["nominal"]["full down"]["seconds"] < 1.0
    assert not result["nominal"]["passivity-bounded"]["crashed"]
    assert result["nominal"]["passivity-bounded"]["seconds"] == pytest.approx(1.0)
    assert result["nominal"]["passivity-bounded"]["max_settled"] is None  # the 1-s episode never reaches 10 s
    _png(out)


def test_episode_summary():
    import numpy as np

    from softpvtol_gym.baselines.figures.tracking import episode_summary

    t = np.arange(0.0, 12.01, 0.5)
    err = np.where(t < 3.0, 5.0, 0.1)
    err[t == 11.0] = 0.3
    run = {"t": t, "err": err, "rms": 1.0, "crashed": False}
    assert episode_summary(run) == {"rms": 1.0, "crashed": False, "seconds": 12.0, "first_close": 3.0,
                                    "max_settled": 0.3}
    assert episode_summary({**run, "err": err + 1.0})["first_close"] is None


def test_without_matplotlib_it_names_the_extra(tmp_path, capsys, monkeypatch):
    import softpvtol_gym.baselines.util.extras as extras

    real = extras.installed

    def no_matplotlib(name):
        return name.split(".")[0] not in ("matplotlib",) and real(name)

    monkeypatch.setattr(extras, "installed", no_matplotlib)
    with pytest.raises(SystemExit) as exc:
        main(["--only", "curves", "--curves-out", str(tmp_path / "c.png")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "missing matplotlib" in err and "softpvtol-gym[baselines]" in err, err
    assert not (tmp_path / "c.png").exists()
