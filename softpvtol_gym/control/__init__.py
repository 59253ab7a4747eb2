"""The paper's analytic controller: passivity-based tracking, control allocation, closed loops."""

from .allocation import ALLOCATION_METHODS, AllocationInfo, allocate
from .closed_loop import LOOPS, MAX_HELD_CONTROL_PERIOD, ControlOutput, PassivityController, simulate_closed_loop
from .extended import ExtendedController, ExtendedGains, ExtendedOutput, simulate_extended_loop
from .passivity import PassivityGains, passivity_control, storage_function
from .references import hover_reference, paper_reference

__all__ = [
    "MPCOptions",
    "ALLOCATION_METHODS", "AllocationInfo", "allocate", "LOOPS", "MAX_HELD_CONTROL_PERIOD", "ControlOutput",
    "PassivityController", "ExtendedController", "ExtendedGains", "ExtendedOutput", "simulate_extended_loop",
    "simulate_closed_loop", "PassivityGains", "passivity_control", "storage_function",
    "hover_reference", "paper_reference",
]


def __getattr__(name: str):
    """``MPCOptions`` (:mod:`.mpc`), imported on first use (PEP 562) so that importing the package does not load
    the MPC's modules."""
    if name == "MPCOptions":
        from .mpc import MPCOptions

        return MPCOptions
    if name == "MPCPolicy":
        raise AttributeError("MPCPolicy acts from observations and lives with the other policies: "
                             "from softpvtol_gym import MPCPolicy (softpvtol_gym.policies.MPCPolicy)")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
