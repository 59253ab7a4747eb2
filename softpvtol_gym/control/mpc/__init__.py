"""Nonlinear model-predictive control of the Soft-PVTOL on CasADi (the optional extra
``pip install 'softpvtol-gym[mpc]'``).

===================  ===========================================================================
:mod:`.symbolic`     the paper's model as CasADi expressions (checked against the numeric kernels)
:mod:`.ocp`          the tracking problem, its options and the real-time-iteration solver
:mod:`._kernels`     the compiled condensing of the QP
:mod:`.policy`       :class:`MPCPolicy`, the SB3-style ``predict`` on observations
===================  ===========================================================================

Importing this package does not import CasADi; building a policy does (ImportError naming the extra
when it is missing).
"""

from .ocp import QP_SOLVERS, MPCOptions
from .policy import MPCPolicy

__all__ = ["MPCPolicy", "MPCOptions", "QP_SOLVERS"]
