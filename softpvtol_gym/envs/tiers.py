"""Robustness tiers: which disturbance effects an episode has, declared once.

An effect is a kernel branch of the env step with its options (:data:`EFFECT_OPTIONS`); a tier is a
named set of effects (:class:`TierSpec`). Adding a tier built from the existing effects is one
:func:`register_tier` call; a new effect is one entry in :data:`EFFECT_OPTIONS` and the defaults
here plus its branch in the step kernel.

The registry itself is :mod:`softpvtol_gym.registry` (shared with the tasks); this module registers
the built-in tiers and re-exports the tier functions. ``TIERS`` is a live lookup: the names
registered at the time it is read (as :func:`registered_tiers`); :data:`BUILTIN_TIERS` are the
built-in ones.
"""

from __future__ import annotations

from ..registry import EFFECT_OPTIONS, TierSpec, get_tier, register_tier, registered_tiers
from ._validation import positive_number, short_repr

__all__ = [
    "TIERS",  # noqa: F822 (a live lookup: module __getattr__)
    "TierSpec", "register_tier", "get_tier", "registered_tiers", "BUILTIN_TIERS", "EFFECT_OPTIONS",
    "DEFAULT_TIER_OPTIONS", "OBS_NOISE_Q", "OBS_NOISE_QD", "check_tier_options", "tier_values",
]

#: default option values (every effect's options)
DEFAULT_TIER_OPTIONS = {
    "mismatch_scale": 0.2,  # plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(1 - s, 1 + s)
    "wind_std": 3.0,  # N, stationary std of the OU force on x and z
    "wind_correlation_time": 1.0,  # s
    "obs_noise_scale": 1.0,  # multiplies OBS_NOISE_Q / OBS_NOISE_QD
    "actuator_time_constant": 0.05,  # s, first-order lag of the applied command
}
_EFFECT_OF = {opt: eff for eff, opts in EFFECT_OPTIONS.items() for opt in opts}
#: options whose "off" value is not 0 (kept as given when the effect is off)
_KEPT_WHEN_OFF = ("wind_correlation_time",)

# observation-noise std of the measured state (noise effect), per q and qdot entry
OBS_NOISE_Q = (0.02, 0.02, 0.01, 0.02, 0.02)  # m, m, rad, rad, rad
OBS_NOISE_QD = (0.05, 0.05, 0.02, 0.05, 0.05)  # m/s, m/s, rad/s, rad/s, rad/s


_BUILTIN = (
    TierSpec("nominal", (), "the nominal plant, no disturbance"),
    TierSpec("mismatch", ("mismatch",), "plant masses, inertias and arm lengths x U(0.8, 1.2) per episode"),
    TierSpec("wind", ("wind",), "Ornstein-Uhlenbeck force on x and z, std 3 N, correlation time 1 s"),
    TierSpec("noisy", ("noise", "lag"), "Gaussian measurement noise and a 0.05 s first-order actuator lag"),
    TierSpec("hard", ("mismatch", "wind", "noise", "lag"), "all of the above"),
    TierSpec("model_gap", ("consistent_plant",),
             "the plant is the consistent model (rotor masses at the rotated tips, virtual-work input map); "
             "the controllers, the allocation and PassivityPolicy keep the paper's model"),
)
for _spec in _BUILTIN:
    register_tier(_spec)
#: the names of the built-in tiers (``TIERS``: every registered one)
BUILTIN_TIERS: tuple[str, ...] = tuple(s.name for s in _BUILTIN)


def __getattr__(name: str):
    """``TIERS``: the names of the tiers registered now (a live lookup, PEP 562)."""
    if name == "TIERS":
        return registered_tiers()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | {"TIERS"})


def check_tier_options(options) -> None:
    if options is None:
        return
    if not isinstance(options, dict):
        raise ValueError(f"tier_options must be a dict with keys from {sorted(DEFAULT_TIER_OPTIONS)} (or None), got "
                         f"{short_repr(options)} of type {type(options).__name__}")
    for k, v in options.items():
        if not isinstance(k, str) or k not in DEFAULT_TIER_OPTIONS:
            raise ValueError(f"unknown tier option {k!r}; valid ones are {sorted(DEFAULT_TIER_OPTIONS)}")
        x = positive_number(f"tier_options[{k!r}]", v, allow_zero=k not in _KEPT_WHEN_OFF)
        if k == "mismatch_scale" and x >= 1.0:
            raise ValueError(f"tier_options['mismatch_scale'] must be in [0, 1) (the plant's masses, inertias and "
                             f"lengths are scaled by U(1 - s, 1 + s), which must stay > 0), got {v!r}")


def tier_values(tier: str, options: dict | None) -> dict:
    """Option values in effect: options of effects that are off are reported as 0 (off)."""
    given = dict(options or {})
    enabled = set(get_tier(tier).effects) | {_EFFECT_OF[k] for k in given}
    vals = dict(DEFAULT_TIER_OPTIONS, **given)
    return {k: (float(v) if (_EFFECT_OF[k] in enabled or k in _KEPT_WHEN_OFF) else 0.0) for k, v in vals.items()}
