"""Packed array layouts declared once as ordered (name, width) fields.

The compiled kernels keep the state of many envs (and the controller's memory, and the SIMD lane
blocks) in a few flat arrays, because each extra argument of a compiled call costs time. A
:class:`Columns` is the one declaration of such an array's columns: the offsets the kernels use
(``layout.at.q``: a namedtuple of ints, which numba freezes into compile-time constants), the named
views the Python side reads (:meth:`Columns.views`) and a signature stored with pickled state, so
that state saved under another layout is refused instead of being read wrongly.
"""

from __future__ import annotations

from collections import namedtuple


class Columns:
    """Columns of a packed array: ``fields`` is an ordered sequence of (name, width).

    Attributes: ``at`` (namedtuple of the fields' first columns), ``size`` (total width),
    ``widths`` (dict name -> width), ``signature`` (hashable, identifies the layout).
    """

    def __init__(self, name: str, fields, version: int = 1):
        names = [f for f, _ in fields]
        if len(set(names)) != len(names):
            raise ValueError(f"layout {name!r} declares a field twice: {names}")
        self.name = name
        self.version = version
        self.fields = tuple((str(f), int(w)) for f, w in fields)
        self.widths = dict(self.fields)
        offsets = []
        o = 0
        for f, w in self.fields:
            if w < 1:
                raise ValueError(f"layout {name!r}: field {f!r} has width {w} < 1")
            offsets.append(o)
            o += w
        self.size = o
        self.at = namedtuple(f"{name}_columns", names)(*offsets)

    @property
    def signature(self) -> tuple:
        return (self.name, self.version, self.fields)

    def extend(self, name: str, fields, version: int = 1) -> Columns:
        """A layout with this one's fields first, then ``fields``."""
        return Columns(name, self.fields + tuple(fields), version)

    def views(self, array) -> dict:
        """{field: view of array[:, columns]} (1-D views for width-1 fields)."""
        out = {}
        for f, w in self.fields:
            o = getattr(self.at, f)
            out[f] = array[:, o] if w == 1 else array[:, o:o + w]
        return out

    def check(self, signature) -> None:
        """Raise if state saved under ``signature`` was not saved under this layout."""
        if tuple(signature) != self.signature:
            raise ValueError(
                f"the saved state was packed with layout {signature!r}, but this version of softpvtol_gym "
                f"uses {self.signature!r}; recreate the env instead of unpickling an old one"
            )

    def __repr__(self) -> str:
        return f"Columns({self.name!r}, {list(self.fields)!r}, version={self.version})"
