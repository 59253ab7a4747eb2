"""CasADi and PIQP, the optional dependencies of the MPC: imported on first use, with an error that names the extra."""

from __future__ import annotations

import importlib

#: the casadi versions the MPC is written for (pyproject's ``mpc`` extra)
CASADI_REQUIREMENT = "casadi>=3.6,<4"
#: the PIQP versions the MPC is written for (pyproject's ``mpc`` extra; 0.7: two-sided inequalities)
PIQP_REQUIREMENT = "piqp>=0.7,<1"
INSTALL_HINT = 'pip install "softpvtol-gym[mpc]"'


def _import_or_explain(module: str, needs: str, requirement: str, alternative: str = ""):
    """The module ``module``, or an ImportError: what needs it, the extra and the requirement to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(
            f"{needs} ({requirement}), which is not installed: {INSTALL_HINT} (or pip install \"{requirement}\")"
            f"{alternative}") from exc


def import_casadi():
    """The ``casadi`` module, or an ImportError that says how to install it."""
    return _import_or_explain("casadi", "the nonlinear MPC (softpvtol_gym.MPCPolicy) needs CasADi",
                              CASADI_REQUIREMENT)


def import_piqp():
    """The ``piqp`` module, or an ImportError that says how to install it (or to choose another solver)."""
    return _import_or_explain("piqp", "the nonlinear MPC's default QP solver is PIQP", PIQP_REQUIREMENT,
                              ', or pass qp_solver="hpipm" (bundled with CasADi, about twice as slow per solve)')
