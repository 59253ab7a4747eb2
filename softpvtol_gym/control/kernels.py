"""Compiled kernels of the control package, by job: the passivity law and storage
(:mod:`._passivity_kernels`), the allocations (:mod:`._allocation_kernels`) and the controller block
driver (:mod:`._block_kernels`). This module gathers their names (``CK.name``)."""

from ._allocation_kernels import *  # noqa: F403
from ._allocation_kernels import _lever  # noqa: F401
from ._block_kernels import *  # noqa: F403
from ._passivity_kernels import *  # noqa: F403
