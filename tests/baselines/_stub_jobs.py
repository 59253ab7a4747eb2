"""Light stand-ins for leaderboard jobs (standard library only, so that a spawned worker starts in a fraction of a
second): the executor and interrupt tests (test_io_errors.py, test_interrupts.py) run them instead of training or
evaluating."""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class StubJob:
    name: str

    def folder(self, root: Path) -> Path:
        return Path(root) / self.name


def stub_entry(job, root, reevaluate=False, token=None, base=None):
    """The job named ``killed`` kills its own worker (SIGKILL); the others count their runs in a marker file."""
    if job.name == "killed":
        os.kill(os.getpid(), signal.SIGKILL)
    marker = Path(root) / f"{job.name}.runs"
    marker.write_text(str(int(marker.read_text()) + 1 if marker.exists() else 1))
    return job.name, 0.0


def sleeping_entry(job, root, reevaluate=False, token=None, base=None):
    """Runs for a minute (interrupt tests); writes its pid first (whole: written aside, then renamed)."""
    pid_file = Path(root) / f"{job.name}.pid"
    pid_file.with_suffix(".tmp").write_text(str(os.getpid()))
    os.replace(pid_file.with_suffix(".tmp"), pid_file)
    time.sleep(60)
    return job.name, 60.0


def environment_variable(name: str) -> str | None:
    """The worker's value of an environment variable."""
    return os.environ.get(name)
