"""Environment variables for child processes only.

A process started with ``spawn`` gets a copy of the parent's ``os.environ`` at its start. To give workers a
variable (e.g. ``NUMBA_NUM_THREADS=1``) without keeping it in the parent, set it around the start only
(:func:`temporary_environment`). A lasting ``NUMBA_*`` change in the parent is worse than a stray variable:
numba reloads its whole configuration at the parent's next compile, the cache directory the package set
included, and would then compile into the source tree.

Standard library only.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator


@contextlib.contextmanager
def temporary_environment(variables: dict[str, str]) -> Iterator[None]:
    """``os.environ`` with ``variables`` set inside the block, restored (set, changed or removed) on leaving."""
    saved = {name: os.environ.get(name) for name in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
