"""Ctrl-C and SIGTERM: every command ends with exit 130 / 143 and one line saying what was kept, leaves no
worker (or Ray) process behind and writes no half result; its help and the docs list the exit codes."""

from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from softpvtol_gym.baselines.util import args as args_mod
from softpvtol_gym.baselines.util.args import EXIT_SIGINT, EXIT_SIGTERM, command_main
from tests.baselines._commands import (
    ENV,
    REPO,
    SOFTPVTOL,
    catches,
    children,
    handles_sigterm,
    one_error_line,
    signal_when,
    write_spec,
)

# ------------------------------------------------------------------------------------------ interrupts
DRIVER = textwrap.dedent("""
    import sys
    from pathlib import Path
    sys.path.insert(0, {tests!r})
    from _stub_jobs import StubJob, sleeping_entry
    from softpvtol_gym.baselines.leaderboard.jobs import run_jobs
    from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor
    from softpvtol_gym.baselines.util.args import command_main

    def body(argv, layout, prog):
        jobs = [StubJob(f"job{{i}}") for i in range(int(argv[0]))]
        with ProcessPerJobExecutor(max_workers=2) as ex:
            run_jobs(jobs, ex, Path(argv[1]), progress=False, rerun="softpvtol run-jobs", entry=sleeping_entry)
        return 0

    if __name__ == "__main__":
        sys.exit(command_main("run_jobs.py", body, "driver")(sys.argv[1:], prog="softpvtol run-jobs"))
""")


@pytest.mark.parametrize("sig, code, words", [(signal.SIGTERM, EXIT_SIGTERM, "terminated (SIGTERM)"),
                                              (signal.SIGINT, EXIT_SIGINT, "interrupted (Ctrl-C)")])
def test_run_jobs_interrupted_stops_its_workers_and_says_what_was_kept(sig, code, words, tmp_path):
    """The job runner in a real process, two one-minute jobs in flight: the signal ends it at once with exit
    143 / 130, one line saying how many jobs finished and how to continue, and no worker left."""
    root = tmp_path / "runs"
    root.mkdir()
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER.format(tests=str(Path(__file__).parent)))
    workers: list[int] = []

    def both_workers_running(proc) -> bool:
        pids = list(root.glob("*.pid"))
        if len(pids) < 2:
            return False
        workers.extend(int(p.read_text()) for p in pids)
        assert catches(proc.pid, sig), f"the driver has no handler for {signal.Signals(sig).name}"
        return True

    # the signal goes to the driver only: its workers must be stopped by it
    pid, returncode, err = signal_when([sys.executable, str(driver), "3", str(root)], both_workers_running, sig,
                                       cwd=tmp_path, timeout=120, from_a_terminal=True)
    assert returncode == code, err
    line = one_error_line(err)
    assert line.startswith(f"softpvtol run-jobs: error: {words}: 0 of 3 jobs finished"), line
    assert "rerun: softpvtol run-jobs" in line, line
    assert not children(pid)
    for pid in workers:
        assert not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]


def test_passivity_metrics_terminated_exits_143_and_writes_no_report(tmp_path):
    out = tmp_path / "p.json"
    _, returncode, err = signal_when([*SOFTPVTOL, "passivity-metrics", "--episodes", "10000", "--json", str(out)],
                                     lambda proc: handles_sigterm(proc.pid), signal.SIGTERM, cwd=tmp_path, delay=1.0)
    assert returncode == EXIT_SIGTERM, err
    line = one_error_line(err)
    assert "terminated (SIGTERM)" in line and "not written" in line, line
    assert not out.exists() and not list(tmp_path.glob(".p.json.*"))


def test_sigterm_handler_is_restored_after_the_command():
    before = signal.getsignal(signal.SIGTERM)
    main = command_main("train.py", lambda argv, layout, prog: 0, "test")
    assert main([]) == 0
    assert signal.getsignal(signal.SIGTERM) is before


def test_every_command_help_lists_the_exit_codes(capsys):
    from softpvtol_gym.baselines.cli import COMMANDS, run_command

    for name in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            run_command(name, ["--help"])
        assert exc.value.code == 0
        out = " ".join(capsys.readouterr().out.split())
        assert "exit codes: 0 done; 2 bad input" in out and "74 input/output error" in out, name
        assert "130 Ctrl-C, 143 SIGTERM" in out, name


def test_the_exit_codes_are_documented():
    text = (REPO / "docs" / "baselines.md").read_text()
    assert "## Exit codes and interrupts" in text
    for code in args_mod.EXIT_CODES:
        assert f"`{code}`" in text


# ------------------------------------------------------------------------------------------ Ray (slow)
def _ray_processes() -> list[str]:
    """Ray processes (raylet, GCS, workers) running on this machine now."""
    procs = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if any(k in cmd for k in ("raylet", "gcs_server", "default_worker.py", "ray::")):
                procs.append(f"{d.name}: {cmd[:80]}")
    return procs


def _ray_leftovers(temp_dir: Path) -> list[str]:
    """Ray processes and the folders the command left in its temporary directory (Ray's session folders, a
    search's storage): the command runs with TMPDIR=temp_dir, so another test's folders are not counted."""
    return _ray_processes() + [str(p) for pattern in ("ray-*", "softpvtol-tune-*") for p in temp_dir.glob(pattern)]


@pytest.fixture
def command_temp_dir():
    """A short, empty TMPDIR for a command that starts Ray (its Unix sockets need a short path)."""
    path = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def _signal_command(argv: list[str], cwd: Path, ready: str, sig: int, delay: float,
                    temp_dir: Path) -> tuple[int, str]:
    """Run ``softpvtol argv`` in ``cwd`` with TMPDIR=temp_dir; once it handles SIGTERM (the command has started)
    and its stdout shows ``ready``, wait ``delay`` s more and send ``sig``."""
    out = cwd / "stdout.txt"
    with open(out, "w") as fh:
        pid, returncode, err = signal_when(
            [*SOFTPVTOL, *argv], lambda proc: handles_sigterm(proc.pid) and ready in out.read_text(), sig, cwd=cwd,
            env={**ENV, "TMPDIR": str(temp_dir)}, stdout=fh, delay=delay, timeout=240, from_a_terminal=True)
    _wait_for_ray_to_exit()
    assert not children(pid)
    return returncode, err


#: how long Ray's processes may take to exit after the command that stopped them (they exit asynchronously after
#: ``ray.shutdown``: 2-10 s measured on the 2-core machine, longer while another job loads it)
RAY_EXIT_SECONDS = 30.0


def _wait_for_ray_to_exit() -> None:
    deadline = time.monotonic() + RAY_EXIT_SECONDS
    while _ray_processes() and time.monotonic() < deadline:
        time.sleep(0.2)


@pytest.mark.slow  # a local Ray instance, twice: ~40 s
@pytest.mark.xdist_group("ray")
@pytest.mark.parametrize("when", ["starting", "running"])
def test_run_jobs_on_ray_terminated_leaves_no_ray_process_or_temp_folder(when, tmp_path, command_temp_dir):
    pytest.importorskip("ray")
    _wait_for_ray_to_exit()  # an earlier test's Ray may still be shutting down
    if _ray_processes():
        pytest.skip(f"another Ray is running here: {_ray_processes()[:2]}")
    # 4 jobs of 10,000 episodes: still running 8 s after Ray's start on a fast machine (one job of 5,000 took 5 s
    # on an AMX Xeon, and the SIGTERM then reached a process that had finished); SIGTERM ends them long before
    spec = write_spec(tmp_path, episodes=10000, passivity=4)
    ready = "Ray:" if when == "running" else ""
    code, err = _signal_command(["run-jobs", "--executor", "ray", "--workers", "1", "--spec", str(spec), "--root",
                                 "runs"], tmp_path, ready, signal.SIGTERM, 8.0 if when == "running" else 4.0,
                                command_temp_dir)
    assert code == EXIT_SIGTERM, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("softpvtol run-jobs: error: terminated (SIGTERM): "), err
    assert "rerun: softpvtol run-jobs --executor ray" in line, line
    assert "Traceback" not in err and not _ray_leftovers(command_temp_dir)
    assert not (tmp_path / "runs" / ".run_jobs.token").exists()


@pytest.mark.slow  # a local Ray Tune search, interrupted: ~30 s
@pytest.mark.xdist_group("ray")
def test_tune_interrupted_writes_no_best_configuration(tmp_path, command_temp_dir):
    pytest.importorskip("ray")
    _wait_for_ray_to_exit()  # an earlier test's Ray may still be shutting down
    if _ray_processes():
        pytest.skip(f"another Ray is running here: {_ray_processes()[:2]}")
    space = tmp_path / "space.yml"
    space.write_text("ppo:\n  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n  n_epochs: {randint: [1, 2]}\n")
    code, err = _signal_command(["tune", "--trials", "4", "--workers", "1", "--space", str(space), "--out", "best.yml",
                                 "--hp", "n_envs=4", "--hp", "n_steps=32", "--hp", "batch_size=64", "--timesteps",
                                 "100000", "--reports", "4", "--eval-episodes", "2"], tmp_path, "Ray Tune:",
                                signal.SIGINT, 10.0, command_temp_dir)
    assert code == EXIT_SIGINT, err
    line = err.strip().splitlines()[-1]
    assert "interrupted (Ctrl-C): the search was stopped before its end, so no best configuration was written" in line
    assert "restore" not in err.lower() and "Traceback" not in err
    assert not (tmp_path / "best.yml").exists() and not _ray_leftovers(command_temp_dir)


@pytest.mark.slow  # a real (tiny) training run in a subprocess: torch and SB3 imports, ~60 s on a busy machine
def test_train_terminated_keeps_its_checkpoint_and_says_how_to_resume(tmp_path):
    out = tmp_path / "run"
    pid, returncode, err = signal_when(
        [*SOFTPVTOL, "train", "--out", str(out), "--timesteps", "10000000", "--n-envs", "4", "--hp", "n_steps=32",
         "--hp", "batch_size=64", "--checkpoint-freq", "256", "--eval-episodes", "0", "--no-progress-bar"],
        lambda proc: (out / "checkpoints" / "latest").is_file(), signal.SIGTERM, cwd=tmp_path)
    assert returncode == EXIT_SIGTERM, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("softpvtol train: error: terminated (SIGTERM): the run in") and "--resume" in line, err
    assert "Traceback" not in err and not (out / "result.json").exists() and not children(pid)


def test_an_interrupt_that_surfaces_as_another_error_is_still_an_interrupt(capsys):
    """SIGTERM inside code that turns the exception into another one (numba's compiler does: it then fails to
    cache the half-compiled kernel with a RuntimeError) still exits 143 with the one-line message."""

    def body(argv, layout, prog):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises here
        except KeyboardInterrupt:
            raise RuntimeError("no compiled object yet") from None
        return 0

    main = command_main("train.py", body, "test")
    with pytest.raises(SystemExit) as info:
        main([])
    assert info.value.code == EXIT_SIGTERM
    assert "terminated (SIGTERM)" in capsys.readouterr().err

    def crash(argv, layout, prog):  # without a signal, an unexpected error is not disguised
        raise RuntimeError("a real bug")

    with pytest.raises(RuntimeError, match="a real bug"):
        command_main("train.py", crash, "test")([])


# ------------------------------------------------------------------------------- a signal inside LLVM
def _frame_in(filename: str):
    """A frame whose code lives in ``filename``."""
    scope: dict = {}
    exec(compile("import sys\nframe = sys._getframe()", filename, "exec"), scope)
    return scope["frame"]


@pytest.mark.parametrize("handler, exc_type, signum", [
    (args_mod._raise_terminated, args_mod.Terminated, signal.SIGTERM),
    (args_mod._raise_interrupt, KeyboardInterrupt, signal.SIGINT)])
def test_a_signal_inside_llvm_is_delivered_again_not_lost(monkeypatch, handler, exc_type, signum):
    """ctypes prints and drops an exception raised in LLVM's callbacks (a kernel compiling when SIGTERM came): the
    handler sends the signal again a moment later instead; outside LLVM it raises at once."""
    import llvmlite

    sent = []
    monkeypatch.setattr(args_mod.os, "kill", lambda pid, s: sent.append((pid, s)))
    monkeypatch.setattr(args_mod, "_signals_received", [])
    inside = _frame_in(os.path.join(os.path.dirname(llvmlite.__file__), "binding", "executionengine.py"))
    handler(signum, inside)  # no exception: it would be lost
    deadline = time.monotonic() + 5.0
    while not sent and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sent == [(os.getpid(), signum)] and args_mod._signals_received == []
    with pytest.raises(exc_type):
        handler(signum, _frame_in(__file__))
    assert args_mod._signals_received == [signum]
