"""The paper's analytic controller: passivity-based tracking, control allocation, closed loops."""

from .allocation import ALLOCATION_METHODS, AllocationInfo, allocate
from .closed_loop import LOOPS, MAX_HELD_CONTROL_PERIOD, ControlOutput, PassivityController, simulate_closed_loop
from .extended import ExtendedController, ExtendedGains, ExtendedOutput, simulate_extended_loop
from .passivity import PassivityGains, passivity_control, storage_function
from .references import hover_reference, paper_reference

__all__ = [
    "MPCPolicy", "MPCOptions",
    "ALLOCATION_METHODS", "AllocationInfo", "allocate", "LOOPS", "MAX_HELD_CONTROL_PERIOD", "ControlOutput",
    "PassivityController", "ExtendedController", "ExtendedGains", "ExtendedOutput", "simulate_extended_loop",
    "simulate_closed_loop", "PassivityGains", "passivity_control", "storage_function",
    "hover_reference", "paper_reference",
]


def __getattr__(name: str):
    """``MPCPolicy`` and ``MPCOptions`` (:mod:`.mpc`), imported on first use (PEP 562) so that importing
    the package does not load the MPC's modules; building an MPCPolicy needs CasADi."""
    if name in ("MPCPolicy", "MPCOptions"):
        from . import mpc

        return getattr(mpc, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
