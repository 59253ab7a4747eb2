"""CasADi and PIQP, the optional dependencies of the MPC: imported on first use, with an error that names the extra."""

from __future__ import annotations

import importlib

#: the casadi versions the MPC is written for (pyproject's ``mpc`` extra)
CASADI_REQUIREMENT = "casadi>=3.6,<4"
INSTALL_HINT = 'pip install "softpvtol-gym[mpc]"'


def import_casadi():
    """The ``casadi`` module, or an ImportError that says how to install it."""
    try:
        return importlib.import_module("casadi")
    except ImportError as exc:
        raise ImportError(
            f"the nonlinear MPC (softpvtol_gym.MPCPolicy) needs CasADi ({CASADI_REQUIREMENT}), which is not "
            f"installed: {INSTALL_HINT} (or pip install \"{CASADI_REQUIREMENT}\")") from exc


#: the PIQP versions the MPC is written for (pyproject's ``mpc`` extra; 0.7: two-sided inequalities)
PIQP_REQUIREMENT = "piqp>=0.7,<1"


def import_piqp():
    """The ``piqp`` module, or an ImportError that says how to install it (or to choose another solver)."""
    try:
        return importlib.import_module("piqp")
    except ImportError as exc:
        raise ImportError(
            f"the nonlinear MPC's default QP solver is PIQP ({PIQP_REQUIREMENT}), which is not installed: "
            f"{INSTALL_HINT} (or pip install \"{PIQP_REQUIREMENT}\"), or pass qp_solver=\"hpipm\" (bundled "
            f"with CasADi, about twice as slow per solve)") from exc
