"""Issue 22, items 4-6: the commands check their outputs before any work, turn an OSError (disk full, read-only,
permission) into one line naming the path (exit 74), report a killed worker without stopping the other jobs,
refuse a malformed or non-finite leaderboard input without writing anything, and end on Ctrl-C / SIGTERM with exit
130 / 143, one line saying what was kept, and no worker process left behind.

The tests run as root in CI containers, where ``chmod`` stops nothing: unwritable outputs are paths under
/proc and /sys, a file used as a directory, and ``os`` functions patched to raise the OSError a full disk or a
read-only mount raises.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from _stub_jobs import StubJob, stub_entry

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, run_jobs
from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor, WorkerCrashed
from softpvtol_gym.baselines.util import args as args_mod
from softpvtol_gym.baselines.util.args import EXIT_IO_ERROR, EXIT_SIGINT, EXIT_SIGTERM, command_main
from softpvtol_gym.baselines.util.atomic import atomic_write_all

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH")) if p),
       "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"}


def _one_error_line(err: str) -> str:
    compiling = ("softpvtol_gym: compil", "softpvtol_gym: ... still compiling")  # compile announcements
    lines = [line for line in err.strip().splitlines() if not line.startswith(compiling)]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]


# ------------------------------------------------------------------------- outputs checked before any work
def _write_spec(tmp: Path, episodes: int = 2, passivity: int = 1) -> Path:
    spec = tmp / "spec.yml"
    names = ", ".join(f"{{name: p{i}, allocation: exact}}" for i in range(passivity))
    spec.write_text(f"evaluation: {{episodes: {episodes}, seed: 1000000, tiers: [nominal]}}\n"
                    f"passivity: [{names}]\ntasks: [hover]\ntrained: []\nseeds: []\n")
    return spec


UNWRITABLE = [  # (command, argv builder, the path the message must name)
    ("train", lambda t: ["--out", "/proc/softpvtol_x", "--timesteps", "10"], "/proc"),
    ("train", lambda t: ["--out", str(t / "a_file" / "sub"), "--timesteps", "10"], "a_file"),
    ("render-gif", lambda t: ["--policy", "passivity", "--out", "/proc/x.gif"], "/proc"),
    ("render-gif", lambda t: ["--policy", "passivity", "--out", str(t / "a_file" / "x.gif")], "a_file"),
    ("figures", lambda t: ["--only", "gif", "--gif-out", "/sys/x.gif"], "/sys"),
    ("run-jobs", lambda t: ["--spec", str(_write_spec(t)), "--root", "/proc/softpvtol_runs"], "/proc"),
    ("run-jobs", lambda t: ["--spec", str(_write_spec(t)), "--root", str(t / "a_file" / "runs")], "a_file"),
    ("leaderboard", lambda t: ["--from-json", "--json", str(REPO / "baselines/results/leaderboard.json"),
                               "--markdown", "/sys/l.md", "--chart", str(t / "l.png")], "/sys"),
    ("passivity-metrics", lambda t: ["--json", "/proc/p.json", "--episodes", "1", "--page", str(t / "p.md")],
     "/proc"),
    ("model-figures", lambda t: ["--json", "/proc/m.json", "--t-final", "0.1"], "/proc"),
    ("reproduce-paper", lambda t: ["--out", "/proc/paper", "--no-steady", "--no-plots"], "/proc"),
]


@pytest.mark.parametrize("command, argv, where", UNWRITABLE, ids=[f"{c}-{w}" for c, _, w in UNWRITABLE])
def test_an_unwritable_output_is_refused_before_any_work(command, argv, where, tmp_path, capsys, monkeypatch):
    """Outputs under /proc or /sys, or under a file, are refused at once (exit 2, one line naming the path):
    before training, rendering or simulating anything (the work functions are made to fail if reached)."""
    from softpvtol_gym.baselines.cli import run_command

    (tmp_path / "a_file").write_text("x")
    monkeypatch.chdir(tmp_path)
    import softpvtol_gym.baselines.evaluation as evaluation

    def reached(*a, **k):
        raise AssertionError("work started before the output was checked")

    monkeypatch.setattr(evaluation, "run_episodes", reached)
    with pytest.raises(SystemExit) as exc:
        run_command(command, argv(tmp_path))
    assert exc.value.code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert where in line and "error:" in line, line


@pytest.mark.parametrize("code, words", [(errno.ENOSPC, "disk full"), (errno.EROFS, "read-only"),
                                         (errno.EACCES, "permission denied")])
def test_an_oserror_during_the_work_is_one_line_naming_the_path_exit_74(code, words, capsys):
    """Disk full, a read-only file system or a permission error met while writing: one line naming the path,
    exit code 74 (never a traceback)."""
    def body(argv, layout, prog):
        raise OSError(code, os.strerror(code), "/data/run/checkpoint.safetensors")

    main = command_main("train.py", body, "test")
    with pytest.raises(SystemExit) as exc:
        main([], prog="softpvtol train")
    assert exc.value.code == EXIT_IO_ERROR
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith("softpvtol train: error: cannot write /data/run/checkpoint.safetensors")
    assert words in line, line


def test_disk_full_while_writing_the_leaderboard_changes_no_output(tmp_path, monkeypatch, capsys):
    """The leaderboard's outputs are written together: a full disk half-way (the chart) leaves the page and the
    JSON as they were, and the command ends with one line naming the file, exit 74."""
    from softpvtol_gym.baselines.commands import leaderboard
    from softpvtol_gym.baselines.util import atomic

    md, png = tmp_path / "l.md", tmp_path / "l.png"
    md.write_text("old page")
    png.write_bytes(b"old chart")
    real_open = open

    def full_disk_open(path, mode="r", *a, **k):
        if "w" in mode and Path(path).name.startswith(".l.png."):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real_open(path, mode, *a, **k)

    monkeypatch.setattr(atomic, "open", full_disk_open, raising=False)
    with pytest.raises(SystemExit) as exc:
        leaderboard.main(["--from-json", "--json", str(REPO / "baselines/results/leaderboard.json"),
                          "--markdown", str(md), "--chart", str(png)], prog="leaderboard")
    assert exc.value.code == EXIT_IO_ERROR
    line = _one_error_line(capsys.readouterr().err)
    assert "l.png" in line and "disk full" in line, line
    assert md.read_text() == "old page" and png.read_bytes() == b"old chart"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.md", "l.png"]  # no temporary file left


def test_atomic_write_all_writes_every_file():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        files = {Path(d) / "a.txt": b"a", Path(d) / "sub" / "b.bin": b"\x00b"}
        atomic_write_all(files)
        assert {p: p.read_bytes() for p in files} == files


# ------------------------------------------------------------------------------ leaderboard inputs
def _finished_analytic_root(tmp: Path) -> tuple[Path, Path]:
    """A spec with one analytic job and a hand-written result for it (3 episodes)."""
    spec = _write_spec(tmp)
    root = tmp / "runs"
    (job,) = load_jobs(spec)
    import dataclasses

    episode = {"return": -1.0, "rms_position_error": 0.1, "rms_attitude_error": 0.01, "control_effort": 0.2,
               "crashed": False, "length": 100}
    record = {"job": dataclasses.asdict(job), "checkpoint": None, "train_seconds": None,
              "eval": {"nominal": [dict(episode), dict(episode, rms_position_error=0.2), dict(episode)]}}
    (root / job.name).mkdir(parents=True)
    (root / job.name / EVAL_FILE).write_text(json.dumps(record))
    return spec, root / job.name / EVAL_FILE


@pytest.mark.parametrize("edit, words", [
    (lambda r: r["eval"]["nominal"][1].update(rms_position_error=float("nan")), "rms_position_error"),
    (lambda r: r["eval"]["nominal"][0].update({"return": float("inf")}), "return"),
    (lambda r: r["eval"]["nominal"][2].pop("crashed"), "crashed is missing"),
    (lambda r: r["eval"]["nominal"][0].update(length="100"), "length"),
    (lambda r: r["job"].pop("eval_seed"), "job.eval_seed is missing"),
    (lambda r: r.update(train_seconds=float("nan")), "train_seconds"),
    (lambda r: r["eval"].update(nominal={}), "non-empty list"),
], ids=["nan", "inf", "missing-key", "wrong-type", "missing-job-key", "nan-seconds", "episodes-not-a-list"])
def test_leaderboard_refuses_a_malformed_or_non_finite_result_and_writes_nothing(edit, words, tmp_path, capsys):
    from softpvtol_gym.baselines.commands import leaderboard

    spec, path = _finished_analytic_root(tmp_path)
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))  # json writes NaN / Infinity, as the audit's poisoned files had
    out = tmp_path / "out"
    out.mkdir()
    md = out / "leaderboard.md"
    md.write_text("the committed page")
    with pytest.raises(SystemExit) as exc:
        leaderboard.main(["--root", str(tmp_path / "runs"), "--spec", str(spec), "--json", str(out / "l.json"),
                          "--markdown", str(md), "--chart", str(out / "l.png")], prog="leaderboard")
    assert exc.value.code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert str(path) in line and words in line, line
    assert sorted(p.name for p in out.iterdir()) == ["leaderboard.md"] and md.read_text() == "the committed page"


def test_leaderboard_from_json_refuses_nan_anywhere(tmp_path, capsys):
    from softpvtol_gym.baselines.commands import leaderboard

    data = json.loads((REPO / "baselines/results/leaderboard.json").read_text())
    data["cells"][0]["summary"]["mean_return"] = float("nan")
    src = tmp_path / "l.json"
    src.write_text(json.dumps(data))
    with pytest.raises(SystemExit) as exc:
        leaderboard.main(["--from-json", "--json", str(src), "--markdown", str(tmp_path / "l.md"),
                          "--chart", str(tmp_path / "l.png"), "--force"], prog="leaderboard")
    assert exc.value.code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "cells[0].summary.mean_return is not a finite number" in line and str(src) in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.json"]


# ------------------------------------------------------------------------------------ killed workers
def test_a_killed_worker_fails_only_its_job_and_the_rerun_command_is_printed(tmp_path, capsys):
    jobs = [StubJob(name) for name in ("first", "killed", "third", "fourth")]
    root = tmp_path / "runs"
    root.mkdir()
    with ProcessPerJobExecutor(max_workers=2) as ex, pytest.raises(ConfigError) as exc:
        run_jobs(jobs, ex, root, progress=False, rerun="softpvtol run-jobs --root runs", entry=stub_entry)
    err = capsys.readouterr()
    failed = [line for line in err.err.splitlines() if line.startswith("[failed]")]
    assert len(failed) == 1 and "killed: worker crashed" in failed[0] and "SIGKILL" in failed[0], err.err
    assert "1 of 4 jobs failed" in str(exc.value) and "rerun: softpvtol run-jobs --root runs" in str(exc.value)
    # every other job ran, once
    assert {p.name: p.read_text() for p in root.glob("*.runs")} == {
        f"{name}.runs": "1" for name in ("first", "third", "fourth")}


def test_the_executor_reports_the_signal_that_killed_the_worker():
    with ProcessPerJobExecutor(max_workers=1) as ex:
        fut = ex.submit(os.kill, 0, 0)  # runs os.kill(0, 0) in the child: fine, returns None
        assert fut.result() is None
        fut = ex.submit(os._exit, 3)
        with pytest.raises(WorkerCrashed, match="exited with code 3"):
            fut.result()


# ------------------------------------------------------------------------------------------ interrupts
def _children(pid: int) -> list[int]:
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


def _handles_sigterm(pid: int) -> bool:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


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
    proc = subprocess.Popen([sys.executable, str(driver), "3", str(root)], env=ENV, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(list(root.glob("*.pid"))) < 2:  # both workers are running their job
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        workers = [int(p.read_text()) for p in root.glob("*.pid")]
        assert _handles_sigterm(proc.pid)
        proc.send_signal(sig)  # to the driver only: its workers must be stopped by it
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    line = _one_error_line(err)
    assert line.startswith(f"softpvtol run-jobs: error: {words}: 0 of 3 jobs finished"), line
    assert "rerun: softpvtol run-jobs" in line, line
    assert not _children(proc.pid)
    for pid in workers:
        assert not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]


def test_passivity_metrics_terminated_exits_143_and_writes_no_report(tmp_path):
    out = tmp_path / "p.json"
    proc = subprocess.Popen([sys.executable, "-m", "softpvtol_gym.baselines", "passivity-metrics", "--episodes",
                             "10000", "--json", str(out), "--page", str(tmp_path / "p.md")], env=ENV, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not _handles_sigterm(proc.pid):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == EXIT_SIGTERM, err
    line = _one_error_line(err)
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
def _ray_leftovers() -> list[str]:
    """Ray processes (raylet, GCS, workers) and local Ray temporary folders that exist now."""
    procs = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if any(k in cmd for k in ("raylet", "gcs_server", "default_worker.py", "ray::")):
                procs.append(f"{d.name}: {cmd[:80]}")
    temps = [*Path("/tmp").glob("ray-*"), *Path("/tmp").glob("softpvtol-tune-*")]
    return procs + [str(p) for p in temps]


def _signal_command(argv: list[str], cwd: Path, ready: str, sig: int, delay: float) -> tuple[int, str]:
    """Run ``softpvtol argv`` in ``cwd``; once it handles SIGTERM (the command has started) and its stdout shows
    ``ready``, wait ``delay`` s more and send ``sig``."""
    out = cwd / "stdout.txt"
    with open(out, "w") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "softpvtol_gym.baselines", *argv], env=ENV, cwd=cwd,
                                stdout=fh, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 240
            while not _handles_sigterm(proc.pid) or ready not in out.read_text():
                assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
                time.sleep(0.2)
            time.sleep(delay)
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
    time.sleep(2.0)  # Ray's processes exit asynchronously after shutdown
    assert not _children(proc.pid)
    return proc.returncode, err


@pytest.mark.slow  # a local Ray instance, twice: ~40 s
@pytest.mark.parametrize("when", ["starting", "running"])
def test_run_jobs_on_ray_terminated_leaves_no_ray_process_or_temp_folder(when, tmp_path):
    pytest.importorskip("ray")
    if _ray_leftovers():
        pytest.skip(f"another Ray is running here: {_ray_leftovers()[:2]}")
    # 4 jobs of 10,000 episodes: still running 8 s after Ray's start on a fast machine (one job of 5,000 took 5 s
    # on an AMX Xeon, and the SIGTERM then reached a process that had finished); SIGTERM ends them long before
    spec = _write_spec(tmp_path, episodes=10000, passivity=4)
    ready = "Ray:" if when == "running" else ""
    code, err = _signal_command(["run-jobs", "--executor", "ray", "--workers", "1", "--spec", str(spec), "--root",
                                 "runs"], tmp_path, ready, signal.SIGTERM, 8.0 if when == "running" else 4.0)
    assert code == EXIT_SIGTERM, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("softpvtol run-jobs: error: terminated (SIGTERM): "), err
    assert "rerun: softpvtol run-jobs --executor ray" in line, line
    assert "Traceback" not in err and not _ray_leftovers()
    assert not (tmp_path / "runs" / ".run_jobs.token").exists()


@pytest.mark.slow  # a local Ray Tune search, interrupted: ~30 s
def test_tune_interrupted_writes_no_best_configuration(tmp_path):
    pytest.importorskip("ray")
    if _ray_leftovers():
        pytest.skip(f"another Ray is running here: {_ray_leftovers()[:2]}")
    space = tmp_path / "space.yml"
    space.write_text("ppo:\n  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n  n_epochs: {randint: [1, 2]}\n")
    code, err = _signal_command(["tune", "--trials", "4", "--workers", "1", "--space", str(space), "--out", "best.yml",
                                 "--hp", "n_envs=4", "--hp", "n_steps=32", "--hp", "batch_size=64", "--timesteps",
                                 "100000", "--reports", "4", "--eval-episodes", "2"], tmp_path, "Ray Tune:",
                                signal.SIGINT, 10.0)
    assert code == EXIT_SIGINT, err
    line = err.strip().splitlines()[-1]
    assert "interrupted (Ctrl-C): the search was stopped before its end, so no best configuration was written" in line
    assert "restore" not in err.lower() and "Traceback" not in err
    assert not (tmp_path / "best.yml").exists() and not _ray_leftovers()


@pytest.mark.slow  # a real (tiny) training run in a subprocess: torch and SB3 imports, ~60 s on a busy machine
def test_train_terminated_keeps_its_checkpoint_and_says_how_to_resume(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "softpvtol_gym.baselines", "train", "--out", str(out),
                             "--timesteps", "10000000", "--n-envs", "4", "--hp", "n_steps=32", "--hp", "batch_size=64",
                             "--checkpoint-freq", "256", "--eval-episodes", "0", "--no-progress-bar"],
                            env=ENV, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out / "checkpoints" / "latest").is_file():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == EXIT_SIGTERM, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("softpvtol train: error: terminated (SIGTERM): the run in") and "--resume" in line, err
    assert "Traceback" not in err and not (out / "result.json").exists() and not _children(proc.pid)


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
