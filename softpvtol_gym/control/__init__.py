"""The paper's analytic controller: passivity-based tracking, control allocation, closed loops."""

from .allocation import ALLOCATION_METHODS, AllocationInfo, allocate
from .closed_loop import LOOPS, ControlOutput, PassivityController, simulate_closed_loop
from .passivity import PassivityGains, passivity_control, storage_function
from .references import hover_reference, paper_reference

__all__ = [
    "ALLOCATION_METHODS", "AllocationInfo", "allocate", "LOOPS", "ControlOutput", "PassivityController",
    "simulate_closed_loop", "PassivityGains", "passivity_control", "storage_function",
    "hover_reference", "paper_reference",
]
