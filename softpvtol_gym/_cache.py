"""Where numba caches the compiled kernels: one directory per version of the package's source.

numba's ``cache=True`` checks only the source file of the cached function itself, but our kernels
inline functions from other modules (the step kernel inlines the model's RK4, the layouts' column
constants are frozen in): after an edit of ``model/paper.py`` a cached step kernel would silently keep
the old physics. So the cache lives in a directory named after a hash of every ``.py`` file of the
package: any edit starts a fresh cache. The directory is outside the package (a read-only
site-packages works, nothing is written into the source tree):
``$SOFTPVTOL_GYM_CACHE_DIR`` or ``$NUMBA_CACHE_DIR`` or ``$XDG_CACHE_HOME/softpvtol-gym`` (default
``~/.cache/softpvtol-gym``), then ``numba-<hash>``; if that cannot be written, a directory under the
system's temporary directory.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent

#: the cold compile of a first env reset + step (numba, empty cache), measured on the 2-core x86-64
#: development machine (``SOFTPVTOL_GYM_CACHE_DIR=$(mktemp -d) python -c "import softpvtol_gym, numpy as np;
#: e = softpvtol_gym.SoftPVTOLEnv(); e.reset(seed=0); e.step(np.zeros(4))"``): 15 s for the actuators or
#: virtual mode and a vector env, 25 s for the residual mode (its controller too); said by the first-run message
COLD_COMPILE_SECONDS = "15-30"


def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """sha256 (16 hex digits) of the package's .py files (relative paths and contents)."""
    h = hashlib.sha256()
    for f in sorted(package_dir.rglob("*.py")):
        h.update(str(f.relative_to(package_dir)).encode())
        h.update(b"\0")
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cache_base() -> Path:
    env = os.environ.get("SOFTPVTOL_GYM_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "softpvtol-gym"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path):
            pass
        return True
    except OSError:
        return False


def configure_numba_cache() -> Path:
    """Point numba's cache at this source version's directory (before any kernel module is imported);
    if it holds no compiled kernel yet, the first compile says so on stderr (:func:`announce_first_compile`)."""
    from numba.core import config

    name = f"numba-{source_digest()}"
    path = cache_base() / name
    if not _writable(path):
        path = Path(tempfile.gettempdir()) / f"softpvtol-gym-{os.getuid() if hasattr(os, 'getuid') else 0}" / name
        path.mkdir(parents=True, exist_ok=True)
    config.CACHE_DIR = str(path)
    if cache_is_empty(path):
        announce_first_compile()
    return path


def cache_is_empty(path: Path) -> bool:
    """No kernel of this source version compiled yet: no numba index file (``*.nbi``) under ``path``."""
    return next(path.rglob("*.nbi"), None) is None


FIRST_RUN_MESSAGE = (f"softpvtol_gym: compiling kernels (first run only, about {COLD_COMPILE_SECONDS} s; "
                     "later runs load them from the cache) ...")


def announce_first_compile() -> None:
    """Print :data:`FIRST_RUN_MESSAGE` to stderr when numba first compiles a kernel of this package in
    this process (a numba compile event: a kernel loaded from the cache raises none)."""
    from numba.core import event

    class _FirstCompile(event.Listener):
        done = False

        def on_start(self, ev) -> None:
            if self.done:
                return
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            if getattr(getattr(disp, "py_func", None), "__module__", "").startswith(__package__ or "softpvtol_gym"):
                self.done = True
                print(FIRST_RUN_MESSAGE, file=sys.stderr, flush=True)

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", _FirstCompile())
