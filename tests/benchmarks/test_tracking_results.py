"""The committed tracking evaluation (benchmarks/tracking_evaluation.json, from
``python benchmarks/tracking_evaluation.py``): the generated tables are the JSON's, every summary is its
episodes', and the passivity reference still evaluates to the committed figures."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def evaluation():
    path = ROOT / "benchmarks" / "tracking_evaluation.py"
    spec = importlib.util.spec_from_file_location("softpvtol_tracking_evaluation", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, json.loads((ROOT / "benchmarks" / "tracking_evaluation.json").read_text())


def test_tables_are_generated_from_the_json(evaluation):
    module, data = evaluation
    assert (ROOT / "benchmarks" / "TRACKING_EVALUATION.md").read_text() == module.markdown(data)
    text = (ROOT / "benchmarks" / "STUDIES.md").read_text()
    block = text[text.index(module.DOCS_START) + len(module.DOCS_START):text.index(module.DOCS_END)]
    assert block.strip() == module.summary_table(data).strip()


def test_every_cell_summarises_its_episodes(evaluation):
    module, data = evaluation
    runs = [data["reference"], *data["runs"]]
    assert len(data["runs"]) >= 10
    for run in runs:
        assert sorted(run["cells"]) == sorted(f"{t}/{tier}" for t in module.TASKS for tier in module.TIERS)
        for cell in run["cells"].values():
            err = np.array(cell["rms_position_errors"])
            assert cell["episodes"] == len(err) == module.EPISODES
            assert cell["mean_rms_position_error"] == pytest.approx(err.mean(), rel=1e-12)
            assert cell["median_rms_position_error"] == pytest.approx(np.median(err), rel=1e-12)
            assert cell["iqm_rms_position_error"] == pytest.approx(module.iqm(err), rel=1e-12)
            assert 0 <= cell["crash_rate"] <= 1 and cell["mean_control_effort"] >= 0
    for run in data["runs"]:
        assert run["command"].startswith("python train.py --action-mode residual --task track_random ")
        assert f"--seed {run['seed']}" in run["command"] and f"--tier {run['trained_tier']}" in run["command"]


def test_the_passivity_reference_evaluates_to_the_committed_figures(evaluation):
    """One cell of the reference, run again with the current code (the env is deterministic given the seed)."""
    from softpvtol_gym import PassivityPolicy
    from softpvtol_gym.baselines.evaluation import run_episodes
    from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv

    module, data = evaluation
    probe = SoftPVTOLVectorEnv(num_envs=1, action_mode="residual", task="track_random", tier="nominal",
                               controller_loop="bounded")
    eps = run_episodes(PassivityPolicy.from_env(probe), "residual", "track_random", "nominal", module.EPISODES,
                       module.EVAL_SEED, env_kwargs={"controller_loop": "bounded"})
    committed = data["reference"]["cells"]["track_random/nominal"]["rms_position_errors"]
    np.testing.assert_allclose([e["rms_position_error"] for e in eps], committed, rtol=1e-9)
