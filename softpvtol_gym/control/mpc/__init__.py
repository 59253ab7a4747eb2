"""The optimal-control problem of the Soft-PVTOL's nonlinear MPC on CasADi (the optional extra
``pip install 'softpvtol-gym[mpc]'``). The policy that acts from observations with it is
:class:`softpvtol_gym.policies.MPCPolicy` (``softpvtol_gym.MPCPolicy``).

===================  ===========================================================================
:mod:`.symbolic`     the paper's model as CasADi expressions (checked against the numeric kernels)
:mod:`.ocp`          the tracking problem, its options and the real-time-iteration solver
:mod:`._kernels`     the compiled condensing of the QP
===================  ===========================================================================

Importing this package does not import CasADi; building a problem does (ImportError naming the extra
when it is missing).
"""

from ._casadi import import_casadi
from .ocp import ND, NU, NX, QP_SOLVERS, MPCOptions, TrackingOCP, hover_input

__all__ = ["MPCOptions", "QP_SOLVERS", "TrackingOCP", "hover_input", "import_casadi", "ND", "NU", "NX"]
