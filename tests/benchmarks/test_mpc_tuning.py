"""The MPC's hand-set choices are the ones its tuning on the tuning episodes made (benchmarks/mpc_tuning.py)."""

from __future__ import annotations

import json

import pytest

from benchmarks import mpc_tuning
from softpvtol_gym.baselines.evaluation import TUNING_SEED


def _candidate(crashes: int, steady: list) -> dict:
    return {"crashes": crashes, "steady": steady}


def test_the_rule_ignores_crash_counts_a_fisher_test_cannot_tell_apart(monkeypatch):
    monkeypatch.setattr(mpc_tuning, "CELLS", (("hover", "hard", 40),))
    finished = [0.02] * 40
    one_crash = [None] + [0.01] * 39
    assert mpc_tuning.chosen({"a": _candidate(0, finished), "b": _candidate(1, one_crash)}) == "b"
    many = [None] * 8 + [0.001] * 32  # 8 of 40 against none: significantly more
    assert mpc_tuning.chosen({"a": _candidate(0, finished), "b": _candidate(8, many)}) == "a"


def test_the_committed_choices_are_the_rules_and_the_packages():
    data = json.loads(mpc_tuning.OUT.read_text())
    assert data["seed"] == TUNING_SEED and set(data["choices"]) == set(mpc_tuning.CHOICES)
    for name, choice in data["choices"].items():
        assert choice["chosen"] == mpc_tuning.chosen(choice["candidates"]), name
        value = choice["candidates"][choice["chosen"]]["value"]
        current = mpc_tuning.package_setting(name)
        assert (list(current) if isinstance(current, tuple) else current) == pytest.approx(value), (
            f"the package's {name} setting {current} is not the one chosen on the tuning episodes ({value})")
