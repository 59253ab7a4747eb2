"""The model's compiled functions as plain Python, for number types numba cannot compile (CasADi's symbols).

The model's equations are written once, in the Python source of its numba functions. :func:`python_twin` returns
the Python function behind a compiled one, with every compiled function it calls (by a global name) replaced by its
own twin, so that the same source runs on any type with ``+ - * /``: the MPC builds its symbolic model this way
(:mod:`softpvtol_gym.control.mpc.symbolic`). A twin runs the same operations in the same order as the compiled
function; only functions of the model's arithmetic can be twinned (``math.sin`` of a symbol, say, fails: pass the
sine in, as :func:`~softpvtol_gym.model.input_map.generalized_forces_sc` takes it).
"""

from __future__ import annotations

import types
from collections.abc import Callable

from numba.core.dispatcher import Dispatcher

_TWINS: dict[Callable, Callable] = {}


def python_twin(function: Callable) -> Callable:
    """The plain-Python twin of a numba-compiled ``function`` (or of a plain one): the same code, its calls of
    compiled functions bound to their twins. TypeError for something that is not a function."""
    py = function.py_func if isinstance(function, Dispatcher) else function
    if not isinstance(py, types.FunctionType):
        raise TypeError(f"python_twin needs a numba-compiled or a Python function, got {function!r}")
    if py in _TWINS:
        return _TWINS[py]
    namespace = dict(py.__globals__)
    twin = types.FunctionType(py.__code__, namespace, py.__name__, py.__defaults__, py.__closure__)
    twin.__doc__, twin.__qualname__, twin.__module__ = py.__doc__, py.__qualname__, py.__module__
    _TWINS[py] = twin  # before the callees: a function that calls itself
    for name in py.__code__.co_names:
        value = namespace.get(name)
        if isinstance(value, Dispatcher):
            namespace[name] = python_twin(value)
    return twin
