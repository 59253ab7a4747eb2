"""Where numba caches the compiled kernels: one directory per version of the package's source.

numba's ``cache=True`` checks only the source file of the cached function itself, but our kernels
inline functions from other modules (the step kernel inlines the model's RK4, the layouts' column
constants are frozen in): after an edit of ``_kernels.py`` a cached step kernel would silently keep
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
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


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
    """Point numba's cache at this source version's directory (before any kernel module is imported)."""
    from numba.core import config

    name = f"numba-{source_digest()}"
    path = cache_base() / name
    if not _writable(path):
        path = Path(tempfile.gettempdir()) / f"softpvtol-gym-{os.getuid() if hasattr(os, 'getuid') else 0}" / name
        path.mkdir(parents=True, exist_ok=True)
    config.CACHE_DIR = str(path)
    return path
