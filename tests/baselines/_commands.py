"""What the tests of the commands' failure modes share: the environment of a command run in a subprocess, the
one-line error check, a small leaderboard spec, and the process helpers of the interrupt tests (from /proc)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: the environment of a command run in a subprocess: the checkout importable, headless rendering
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p),
       "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"}
#: the ``softpvtol`` command in a subprocess
SOFTPVTOL = [sys.executable, "-m", "softpvtol_gym.baselines"]


def one_error_line(err: str) -> str:
    """The one line a command printed on stderr (compile announcements aside); fails on a traceback or more."""
    compiling = ("softpvtol_gym: compil", "softpvtol_gym: ... still compiling")  # compile announcements
    lines = [line for line in err.strip().splitlines() if not line.startswith(compiling)]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]


def write_spec(tmp: Path, episodes: int = 2, passivity: int = 1) -> Path:
    """A leaderboard spec of ``passivity`` analytic jobs on hover, nominal, ``episodes`` episodes each."""
    spec = tmp / "spec.yml"
    names = ", ".join(f"{{name: p{i}, allocation: exact}}" for i in range(passivity))
    spec.write_text(f"evaluation: {{episodes: {episodes}, seed: 1000000, tiers: [nominal]}}\n"
                    f"passivity: [{names}]\ntasks: [hover]\ntrained: []\nseeds: []\n")
    return spec


def children(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (from /proc)."""
    parents = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents.setdefault(int(fields[1]), []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for c in parents.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def catches(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler installed for ``sig`` (its SigCgt mask)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (sig - 1)))
    return False


def handles_sigterm(pid: int) -> bool:
    return catches(pid, signal.SIGTERM)


def as_from_a_terminal() -> None:
    """Run in a child before it starts: Ctrl-C at its default disposition, as in a shell. An ignored SIGINT is
    inherited, and Python then installs no KeyboardInterrupt handler; the worker processes of a parallel test run
    may ignore it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def signal_when(argv: list[str], ready, sig: int, *, cwd: Path, env: dict | None = None, stdout=subprocess.PIPE,
                delay: float = 0.0, timeout: float = 300.0, from_a_terminal: bool = False) -> tuple[int, int, str]:
    """Run ``argv`` in ``cwd``; once ``ready(proc)`` holds, wait ``delay`` s and send ``sig`` to it alone.
    Returns (pid, exit code, stderr); the process is killed if the test fails before it ended."""
    proc = subprocess.Popen(argv, env=ENV if env is None else env, cwd=cwd, stdout=stdout, stderr=subprocess.PIPE,
                            text=True, preexec_fn=as_from_a_terminal if from_a_terminal else None)
    try:
        deadline = time.monotonic() + timeout
        while not ready(proc):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        time.sleep(delay)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.pid, proc.returncode, err
