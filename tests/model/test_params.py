"""SoftPVTOLParams: defaults, validation, immutability."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from softpvtol_gym import PARAM_FIELDS, SoftPVTOLParams

DEFAULTS = {
    "m": 5.0,
    "m_l": 1.0,
    "m_r": 1.0,
    "I": 1.0,
    "I_l": 0.1,
    "I_r": 0.1,
    "l_l": 0.5,
    "l_r": 0.5,
    "g": 9.8,
    "epsilon": 0.0,
}
POSITIVE = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")
NON_NEGATIVE = ("g", "epsilon")

_BAD_POSITIVE = [0.0, -1.0, -1e-12, math.nan, math.inf, -math.inf]
_BAD_NON_NEGATIVE = [-1.0, -1e-12, math.nan, math.inf, -math.inf]


def _names_field(message: str, name: str) -> bool:
    """The field name appears as a whole identifier (so "m" is not satisfied by "m_l" or "must")."""
    return re.search(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])", message) is not None


def test_defaults():
    p = SoftPVTOLParams()
    assert {f.name: getattr(p, f.name) for f in dataclasses.fields(p)} == DEFAULTS
    assert tuple(PARAM_FIELDS) == tuple(DEFAULTS)
    np.testing.assert_array_equal(p.array, np.array(list(DEFAULTS.values())))


@pytest.mark.parametrize(
    ("name", "value"), [(n, v) for n in POSITIVE for v in _BAD_POSITIVE], ids=lambda x: repr(x)
)
def test_invalid_positive_field_raises(name, value):
    with pytest.raises(ValueError) as info:
        SoftPVTOLParams(**{name: value})
    msg = str(info.value)
    assert _names_field(msg, name), msg
    assert repr(float(value)) in msg, msg


@pytest.mark.parametrize(
    ("name", "value"), [(n, v) for n in NON_NEGATIVE for v in _BAD_NON_NEGATIVE], ids=lambda x: repr(x)
)
def test_invalid_non_negative_field_raises(name, value):
    with pytest.raises(ValueError) as info:
        SoftPVTOLParams(**{name: value})
    msg = str(info.value)
    assert _names_field(msg, name), msg
    assert repr(float(value)) in msg, msg


@pytest.mark.parametrize("name", NON_NEGATIVE)
def test_zero_allowed_for_g_and_epsilon(name):
    p = SoftPVTOLParams(**{name: 0.0})
    assert getattr(p, name) == 0.0


@pytest.mark.parametrize("name", POSITIVE + NON_NEGATIVE)
def test_valid_values_accepted_and_stored_as_float(name):
    p = SoftPVTOLParams(**{name: 2})  # an int is a valid real number
    assert getattr(p, name) == 2.0
    assert type(getattr(p, name)) is float


@pytest.mark.parametrize("name", POSITIVE + NON_NEGATIVE)
def test_replace_revalidates(name):
    with pytest.raises(ValueError, match=re.escape(name)):
        SoftPVTOLParams().replace(**{name: -1.0})


@pytest.mark.parametrize("name", POSITIVE + NON_NEGATIVE)
def test_frozen(name):
    p = SoftPVTOLParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(p, name, 1.0)
    assert getattr(p, name) == DEFAULTS[name]


def test_array_round_trip_and_read_only():
    p = SoftPVTOLParams(m=3.0, epsilon=0.2)
    assert SoftPVTOLParams.from_array(p.array) == p
    with pytest.raises(ValueError):
        p.array[0] = 1.0
