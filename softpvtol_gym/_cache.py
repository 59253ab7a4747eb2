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
import threading
import time
from pathlib import Path

from numba.core import event as _numba_event

PACKAGE_DIR = Path(__file__).resolve().parent

#: the cold compile of a first env reset + step (numba, empty cache) in a fresh process on the 2-core x86-64
#: development machines, import included (``python benchmarks/run.py``, item 5): 11.9 s for the actuators mode
#: and 23.8 s for the residual mode (its controller too) at d0a5872 on an AMX-capable Xeon; 28 s and 49 s at
#: ec88276 on the slower AMD EPYC used before (it compiled more then); said by the first-run message
COLD_COMPILE_SECONDS = "10-50"


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
    """Point numba's cache at this source version's directory (before any kernel module is imported)
    and announce every compile of this package's kernels on stderr (:func:`announce_compiles`)."""
    from numba.core import config

    name = f"numba-{source_digest()}"
    path = cache_base() / name
    if not _writable(path):
        path = Path(tempfile.gettempdir()) / f"softpvtol-gym-{os.getuid() if hasattr(os, 'getuid') else 0}" / name
        path.mkdir(parents=True, exist_ok=True)
    config.CACHE_DIR = str(path)
    _keep_cache_directory(path)
    announce_compiles(first_run=cache_is_empty(path))
    return path


class CacheDirectoryKeeper(_numba_event.Listener):
    """numba reloads its configuration from the ``NUMBA_*`` environment variables at every compile when one of
    them changed (say a user sets ``NUMBA_NUM_THREADS`` after the import); the reload forgets the cache directory
    set here, and a kernel module imported afterwards would cache into the source tree. After each compile this
    puts the directory back if numba has none (a ``NUMBA_CACHE_DIR`` the user sets later is kept)."""

    def __init__(self, path: Path):
        self.path = str(path)

    def on_start(self, ev) -> None:
        pass

    def on_end(self, ev) -> None:
        from numba.core import config

        if not config.CACHE_DIR:
            config.CACHE_DIR = self.path


_KEEPER: CacheDirectoryKeeper | None = None


def _keep_cache_directory(path: Path) -> None:
    global _KEEPER
    if _KEEPER is None:
        _KEEPER = CacheDirectoryKeeper(path)
        _numba_event.register("numba:compile", _KEEPER)


def cache_is_empty(path: Path) -> bool:
    """No kernel of this source version compiled yet: no numba index file (``*.nbi``) under ``path``."""
    return next(path.rglob("*.nbi"), None) is None


FIRST_RUN_MESSAGE = (f"softpvtol_gym: compiling kernels (first run only, about {COLD_COMPILE_SECONDS} s; "
                     "later runs load them from the cache) ...")
#: the lines of every compile (a kernel's first use in this source version; a cached kernel loads silently)
COMPILE_START = "softpvtol_gym: compiling {name} (once; later runs load it from the cache) ..."
COMPILE_PROGRESS = "softpvtol_gym: ... still compiling {name} ({seconds:.0f} s)"
COMPILE_END = "softpvtol_gym: compiled {name} in {seconds:.1f} s"
#: seconds between the progress lines of a long compile (no silence over 10 s)
PROGRESS_SECONDS = 5.0


def _say(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class CompileAnnouncer(_numba_event.Listener):
    """A numba event listener: the outermost compile of a kernel of this package says its start, a
    progress line every :data:`PROGRESS_SECONDS`, and its end with its duration (its callees compile
    inside it and are not announced separately). ``first_run``: an empty cache, also say
    :data:`FIRST_RUN_MESSAGE` once before the first compile. Loading a cached kernel raises no event."""

    def __init__(self, first_run: bool = False, say=_say, progress_seconds: float = PROGRESS_SECONDS):
        self.first_run = first_run
        self.say = say
        self.progress_seconds = progress_seconds
        self.depth = 0
        self.outer = None  # (name, start time, stop event of the progress thread)
        self.lock = threading.Lock()

    @staticmethod
    def _ours(ev):
        disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
        func = getattr(disp, "py_func", None)
        module = getattr(func, "__module__", "") or ""
        if module.startswith(__package__ or "softpvtol_gym"):
            return f"{module.rsplit('.', 1)[-1]}.{func.__name__}"
        return None

    def on_start(self, ev) -> None:
        name = self._ours(ev)
        if name is None:
            return
        with self.lock:
            self.depth += 1
            if self.depth > 1:
                return
            if self.first_run:
                self.first_run = False
                self.say(FIRST_RUN_MESSAGE)
            stop = threading.Event()
            self.outer = (name, time.perf_counter(), stop)
        self.say(COMPILE_START.format(name=name))
        threading.Thread(target=self._progress, args=(name, self.outer[1], stop), daemon=True,
                         name="softpvtol-compile-progress").start()

    def _progress(self, name: str, t0: float, stop: threading.Event) -> None:
        while not stop.wait(self.progress_seconds):
            self.say(COMPILE_PROGRESS.format(name=name, seconds=time.perf_counter() - t0))

    def on_end(self, ev) -> None:
        if self._ours(ev) is None:
            return
        with self.lock:
            self.depth = max(0, self.depth - 1)
            if self.depth or self.outer is None:
                return
            name, t0, stop = self.outer
            self.outer = None
        stop.set()
        self.say(COMPILE_END.format(name=name, seconds=time.perf_counter() - t0))


_ANNOUNCER: CompileAnnouncer | None = None


def announce_compiles(first_run: bool = False) -> CompileAnnouncer:
    """Register (once per process) the :class:`CompileAnnouncer` of this package's kernels."""
    global _ANNOUNCER
    if _ANNOUNCER is None:
        _ANNOUNCER = CompileAnnouncer(first_run)
        _numba_event.register("numba:compile", _ANNOUNCER)
    return _ANNOUNCER
