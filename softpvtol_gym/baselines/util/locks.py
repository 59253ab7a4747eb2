"""Exclusive locks on a run directory or a job root, with the holder named in a sidecar file.

``with DirectoryLock(run_dir, "run directory"):`` holds ``<run_dir>/.softpvtol.lock`` (an OS file lock
through the ``filelock`` library: released by the OS if the process dies, so a killed run never leaves a
stale lock) and writes ``.softpvtol.lock.json`` (pid, host, start time, command). A second process gets
:class:`~softpvtol_gym.baselines.errors.LockedError` at once, naming the holder; scripts turn it into exit code 2.
Within one process and thread the lock is re-entrant (``train.py`` holds its run directory while
:func:`softpvtol_gym.baselines.training.loop.train` takes it again).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import sys
import threading
from pathlib import Path

from filelock import FileLock, Timeout

from softpvtol_gym.baselines.errors import LockedError
from softpvtol_gym.baselines.util.atomic import atomic_write_text
from softpvtol_gym.baselines.util.safe_load import loads_json

LOCK_FILE = ".softpvtol.lock"
OWNER_FILE = ".softpvtol.lock.json"

_held: dict[tuple[str, int], list] = {}  # (resolved directory, thread id) -> [FileLock, depth]
_guard = threading.Lock()


def holder(directory: Path) -> str:
    """The holder of ``directory``'s lock as recorded in its sidecar, in words."""
    try:
        info = loads_json((Path(directory) / OWNER_FILE).read_text(), OWNER_FILE)
        return (f"pid {info['pid']} on host {info['host']} (since {info['since']}, "
                f"command: {info['command']})")
    except (OSError, ValueError, KeyError, TypeError):
        return "another process (its pid/host record is not readable)"


class DirectoryLock:
    """Exclusive, non-blocking lock of a directory (created if missing). ``what`` names it in errors."""

    def __init__(self, directory: Path, what: str = "directory"):
        self.directory = Path(directory)
        self.what = what
        self._key: tuple[str, int] | None = None

    def acquire(self) -> DirectoryLock:
        self.directory.mkdir(parents=True, exist_ok=True)
        key = (str(self.directory.resolve()), threading.get_ident())
        with _guard:
            entry = _held.get(key)
            if entry is not None:
                entry[1] += 1
                self._key = key
                return self
        lock = FileLock(str(self.directory / LOCK_FILE), timeout=0)
        try:
            lock.acquire(timeout=0)
        except Timeout:
            raise LockedError(f"{self.what} {self.directory} is in use by {holder(self.directory)}; wait for it "
                              f"to finish or stop it (nothing was changed)") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "since": _dt.datetime.now().isoformat(timespec="seconds"), "command": " ".join(sys.argv)}
        atomic_write_text(self.directory / OWNER_FILE, json.dumps(info))
        with _guard:
            _held[key] = [lock, 1]
        self._key = key
        return self

    def release(self) -> None:
        key, self._key = self._key, None
        if key is None:
            return
        with _guard:
            entry = _held[key]
            entry[1] -= 1
            if entry[1] > 0:
                return
            del _held[key]
        try:
            (self.directory / OWNER_FILE).unlink()
        except OSError:
            pass
        entry[0].release()

    def __enter__(self) -> DirectoryLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
