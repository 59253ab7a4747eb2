"""model.twin.python_twin: the model's compiled functions as plain Python give the same numbers bit for bit, and
run on types numba cannot compile (what the MPC's symbolic model is built from)."""

from __future__ import annotations

import fractions

import numpy as np
import pytest

from softpvtol_gym.model import input_map, paper, series
from softpvtol_gym.model.twin import python_twin
from softpvtol_gym.params import SoftPVTOLParams


def test_the_twin_of_the_dynamics_gives_the_compiled_numbers_bit_for_bit():
    p = SoftPVTOLParams().array
    rng = np.random.default_rng(0)
    qddot, forces = python_twin(paper.qddot), python_twin(input_map.generalized_forces)
    for _ in range(50):
        q, qd, a = rng.normal(size=5), rng.normal(size=5), rng.normal(size=4) * 10.0
        for code in (input_map.INPUT_MAP_PAPER, input_map.INPUT_MAP_EXACT):
            assert forces(q, a, p, code) == input_map.generalized_forces(q, a, p, code)
        tau = tuple(rng.normal(size=5))
        assert qddot(q[3], q[4], qd[3], qd[4], tau, p) == paper.qddot(q[3], q[4], qd[3], qd[4], tau, p)


def test_a_twin_calls_the_twins_of_what_it_calls_so_it_runs_on_other_number_types():
    basis = python_twin(series.arm_basis)
    exact = basis(fractions.Fraction(1, 3))  # a compiled function refuses a Fraction
    assert all(isinstance(v, float) for v in exact)  # the coefficients are floats, the arithmetic Python's
    assert exact == series.arm_basis(1.0 / 3.0)
    assert python_twin(series.arm_basis) is basis  # one twin per function


def test_what_is_not_a_function_is_refused():
    with pytest.raises(TypeError, match="numba-compiled or a Python function, got 3"):
        python_twin(3)
