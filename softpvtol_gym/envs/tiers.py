"""Robustness tiers: which disturbance effects an episode has, declared once.

An effect is a kernel branch of the env step with its options (:data:`EFFECT_OPTIONS`); a tier is a
named set of effects (:class:`TierSpec`). Adding a tier built from the existing effects is one
:func:`register_tier` call; a new effect is one entry here plus its branch in the step kernel.
"""

from __future__ import annotations

import dataclasses

from ._validation import positive_number, short_repr

#: default option values (every effect's options)
DEFAULT_TIER_OPTIONS = {
    "mismatch_scale": 0.2,  # plant m, m_l, m_r, I, I_l, I_r, l_l, l_r each x U(1 - s, 1 + s)
    "wind_std": 3.0,  # N, stationary std of the OU force on x and z
    "wind_correlation_time": 1.0,  # s
    "obs_noise_scale": 1.0,  # multiplies OBS_NOISE_Q / OBS_NOISE_QD
    "actuator_time_constant": 0.05,  # s, first-order lag of the applied command
}
#: the effects and the options that parametrise each (an option given by hand switches its effect on)
EFFECT_OPTIONS = {
    "mismatch": ("mismatch_scale",),
    "wind": ("wind_std", "wind_correlation_time"),
    "noise": ("obs_noise_scale",),
    "lag": ("actuator_time_constant",),
    # the plant integrates the consistent model (docs/model.md) while the controllers keep the paper's
    "consistent_plant": (),
}
_EFFECT_OF = {opt: eff for eff, opts in EFFECT_OPTIONS.items() for opt in opts}
#: options whose "off" value is not 0 (kept as given when the effect is off)
_KEPT_WHEN_OFF = ("wind_correlation_time",)

# observation-noise std of the measured state (noise effect), per q and qdot entry
OBS_NOISE_Q = (0.02, 0.02, 0.01, 0.02, 0.02)  # m, m, rad, rad, rad
OBS_NOISE_QD = (0.05, 0.05, 0.02, 0.05, 0.05)  # m/s, m/s, rad/s, rad/s, rad/s


@dataclasses.dataclass(frozen=True)
class TierSpec:
    """A robustness tier: ``name`` and the ``effects`` it switches on (keys of :data:`EFFECT_OPTIONS`;
    "consistent_plant" has no options: the plant integrates ``model="consistent"``)."""

    name: str
    effects: tuple = ()
    description: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"TierSpec.name must be a non-empty str, got {self.name!r}")
        unknown = [e for e in self.effects if e not in EFFECT_OPTIONS]
        if unknown:
            raise ValueError(f"unknown tier effects {unknown}; valid ones are {sorted(EFFECT_OPTIONS)}")
        object.__setattr__(self, "effects", tuple(self.effects))


_TIERS: dict[str, TierSpec] = {}


def register_tier(spec: TierSpec, *, overwrite: bool = False) -> TierSpec:
    """Make a tier available to every env by name."""
    if not isinstance(spec, TierSpec):
        raise TypeError(f"register_tier takes a TierSpec, got {type(spec).__name__}")
    if spec.name in _TIERS and not overwrite:
        raise ValueError(f"tier {spec.name!r} is already registered (pass overwrite=True to replace it)")
    _TIERS[spec.name] = spec
    return spec


def get_tier(name) -> TierSpec:
    try:
        return _TIERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"tier must be one of {list(_TIERS)}, got {name!r}") from None


def registered_tiers() -> tuple[str, ...]:
    return tuple(_TIERS)


for _spec in (
    TierSpec("nominal", (), "the nominal plant, no disturbance"),
    TierSpec("mismatch", ("mismatch",), "plant masses, inertias and arm lengths x U(0.8, 1.2) per episode"),
    TierSpec("wind", ("wind",), "Ornstein-Uhlenbeck force on x and z, std 3 N, correlation time 1 s"),
    TierSpec("noisy", ("noise", "lag"), "Gaussian measurement noise and a 0.05 s first-order actuator lag"),
    TierSpec("hard", ("mismatch", "wind", "noise", "lag"), "all of the above"),
    TierSpec("model_gap", ("consistent_plant",),
             "the plant is the consistent model (rotor masses at the rotated tips, virtual-work input map); "
             "the controllers, the allocation and PassivityPolicy keep the paper's model"),
):
    register_tier(_spec)
#: the built-in tiers
TIERS = registered_tiers()


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
