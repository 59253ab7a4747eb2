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

from .._validation import bounded_number, short_repr
from ..registry import EFFECT_OPTIONS, MAX_EPISODE_SECONDS, TierSpec, get_tier, register_tier, registered_tiers

__all__ = [
    "TIERS",  # noqa: F822 (a live lookup: module __getattr__)
    "TierSpec", "register_tier", "get_tier", "registered_tiers", "BUILTIN_TIERS", "EFFECT_OPTIONS",
    "DEFAULT_TIER_OPTIONS", "TIER_OPTION_BOUNDS", "MISMATCH_FIELDS", "FORCE_MAX", "OBS_NOISE_Q", "OBS_NOISE_QD",
    "check_tier_options", "tier_values",
]

#: default option values (every effect's options)
DEFAULT_TIER_OPTIONS = {
    "mismatch_scale": 0.2,  # plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(1 - s, 1 + s)
    "wind_std": 3.0,  # N, stationary std of the OU force on x and z
    "wind_correlation_time": 1.0,  # s
    "obs_noise_scale": 1.0,  # multiplies OBS_NOISE_Q / OBS_NOISE_QD
    "actuator_time_constant": 0.05,  # s, first-order lag of the applied command
}
#: the plant parameters the mismatch effect scales, each by its own U(1 - s, 1 + s) per episode
MISMATCH_FIELDS = ("m", "m_l", "m_r", "I", "I_l", "I_r", "l_l", "l_r")
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


#: the largest force [N] an option may ask for (``wind_std``; ``actuator_limits`` has the same bound):
#: 50 x the largest default arm torque limit the parameter bounds allow (4 g m_l l_l / 2 = 2e18 N m
#: at g, m_l, l_l = 1e6), so every force and the actions it scales stay far inside float64
FORCE_MAX = 1e20

#: (lowest, highest, why) of each tier option; the lowest is excluded where it is 0 for an option
#: whose 0 is not "off" (wind_correlation_time)
TIER_OPTION_BOUNDS = {
    "mismatch_scale": (0.0, 1.0, "the plant's masses, inertias and lengths are scaled by U(1 - s, 1 + s), which "
                                 "must stay > 0"),
    "wind_std": (0.0, FORCE_MAX, f"a force [N]; {FORCE_MAX:g} N is 50 x the largest actuator limit the parameter "
                                 "bounds give by default, far inside float64"),
    "wind_correlation_time": (0.0, MAX_EPISODE_SECONDS, f"[s], > 0; beyond the longest episode "
                                                        f"({MAX_EPISODE_SECONDS:g} s) the force is constant"),
    "obs_noise_scale": (0.0, 1e8, "x the noise stds; at 1e8 the smallest std (0.01 rad) reaches the observation "
                                  "clip of 1e6, every measured entry is clipped noise"),
    "actuator_time_constant": (0.0, MAX_EPISODE_SECONDS, f"[s]; beyond the longest episode "
                                                         f"({MAX_EPISODE_SECONDS:g} s) the command never moves"),
}


def check_tier_options(options) -> None:
    """``tier_options`` (None or a dict of known options) within :data:`TIER_OPTION_BOUNDS`; a ValueError
    naming the option, the value, the range and why otherwise."""
    if options is None:
        return
    if not isinstance(options, dict):
        raise ValueError(f"tier_options must be a dict with keys from {sorted(DEFAULT_TIER_OPTIONS)} (or None), got "
                         f"{short_repr(options)} of type {type(options).__name__}")
    for k, v in options.items():
        if not isinstance(k, str) or k not in DEFAULT_TIER_OPTIONS:
            raise ValueError(f"unknown tier option {k!r}; valid ones are {sorted(DEFAULT_TIER_OPTIONS)}")
        lo, hi, why = TIER_OPTION_BOUNDS[k]
        bounded_number(f"tier_options[{k!r}]", v, lo, hi, why, low_open=k in _KEPT_WHEN_OFF,
                       high_open=k == "mismatch_scale")


def tier_values(tier: str, options: dict | None) -> dict:
    """Option values in effect: options of effects that are off are reported as 0 (off)."""
    given = dict(options or {})
    enabled = set(get_tier(tier).effects) | {_EFFECT_OF[k] for k in given}
    vals = dict(DEFAULT_TIER_OPTIONS, **given)
    return {k: (float(v) if (_EFFECT_OF[k] in enabled or k in _KEPT_WHEN_OFF) else 0.0) for k, v in vals.items()}
