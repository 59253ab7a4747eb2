"""The vector env's reset uniforms drawn from its sub-envs' own generators in one compiled loop.

Each sub-env has its own ``numpy.random.Generator`` (seeded as gymnasium's SyncVectorEnv seeds its
envs); a reset of sub-env i draws ``N_UNIFORMS`` doubles from generator i. A Python loop of
``Generator.random`` calls costs about 1 us per reset sub-env, a large share of a step of thousands of
envs. :class:`UniformDraws` calls the bit generators' own C function (``next_double``, numpy's public
``BitGenerator.ctypes`` interface) on their states from a compiled loop: the same doubles from the same
states, advanced the same way, so the numbers and every generator afterwards are exactly those of the
Python loop. Generators that are not PCG64 (gymnasium's) take the Python loop.
"""

from __future__ import annotations

import ctypes

import numpy as np
from numba import njit

#: the C signature the compiled loop calls: double next_double(void *state), the state as an address
_NEXT_DOUBLE = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_uint64)


@njit(cache=True, nogil=True)
def _draw_rows(next_double, states, idx, out):
    """out[j, :] = the next out.shape[1] doubles of the generator whose state is at states[idx[j]]."""
    for j in range(idx.size):
        s = states[idx[j]]
        for k in range(out.shape[1]):
            out[j, k] = next_double(s)


def python_draws(rngs: list, idx: np.ndarray, n_uniforms: int) -> np.ndarray:
    """The reference: ``rngs[i].random(n_uniforms)`` for i in idx, stacked (len(idx), n_uniforms)."""
    u = np.empty((idx.size, n_uniforms))
    for j, i in enumerate(idx.tolist()):
        rngs[i].random(out=u[j])  # = rngs[i].random(n_uniforms), without a temporary
    return u


class UniformDraws:
    """Draws from a list of generators: :meth:`draw` gives the same numbers as :func:`python_draws`.

    The state addresses are taken once per list (``rngs`` identity) and again after :meth:`invalidate`
    (call it after replacing a generator in the list); the list is held, so the states stay alive."""

    def __init__(self):
        self._rngs = None
        self._states = None
        self._next_double = None

    def __getstate__(self) -> dict:  # a copy (pickle, deepcopy) takes the addresses again, of its own generators
        return {}

    def __setstate__(self, state: dict) -> None:
        self.__init__()

    def invalidate(self) -> None:
        self._rngs = None

    def _table(self, rngs: list) -> bool:
        if self._rngs is rngs:
            return self._states is not None
        self._rngs = rngs
        self._states = None
        bits = [g.bit_generator for g in rngs]
        if not bits or any(type(b) is not np.random.PCG64 for b in bits):
            return False
        self._states = np.array([b.ctypes.state_address for b in bits], dtype=np.uint64)
        address = ctypes.cast(bits[0].ctypes.next_double, ctypes.c_void_p).value
        self._next_double = _NEXT_DOUBLE(address)
        return True

    def draw(self, rngs: list, idx: np.ndarray, n_uniforms: int) -> np.ndarray:
        """``rngs[i].random(n_uniforms)`` for i in idx (an int array), as rows of a (len(idx), n_uniforms) array."""
        if idx.size < 2 or not self._table(rngs):  # (one row: the Python loop is as fast)
            return python_draws(rngs, idx, n_uniforms)
        u = np.empty((idx.size, n_uniforms))
        _draw_rows(self._next_double, self._states, np.ascontiguousarray(idx, dtype=np.int64), u)
        return u
