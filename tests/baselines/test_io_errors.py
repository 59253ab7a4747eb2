"""The commands' input/output failures: an unwritable output is refused before any work (exit 2, one line naming
the path), an OSError met during the work (disk full, read-only, permission) is one line naming the path (exit 74)
and changes no output, a malformed or non-finite leaderboard input is refused without writing anything, and a
killed worker fails only its job.

The tests run as root in CI containers, where ``chmod`` stops nothing: unwritable outputs are paths under /proc
and /sys, a file used as a directory, and ``os`` functions patched to raise the OSError a full disk or a
read-only mount raises.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, run_jobs
from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor, WorkerCrashed
from softpvtol_gym.baselines.util import args as args_mod
from softpvtol_gym.baselines.util.args import EXIT_IO_ERROR, command_main
from softpvtol_gym.baselines.util.atomic import atomic_write_all
from tests.baselines._commands import REPO, one_error_line, write_spec
from tests.baselines._stub_jobs import StubJob, stub_entry

UNWRITABLE = [  # (command, argv builder, the path the message must name)
    ("train", lambda t: ["--out", "/proc/softpvtol_x", "--timesteps", "10"], "/proc"),
    ("train", lambda t: ["--out", str(t / "a_file" / "sub"), "--timesteps", "10"], "a_file"),
    ("render-gif", lambda t: ["--policy", "passivity", "--out", "/proc/x.gif"], "/proc"),
    ("render-gif", lambda t: ["--policy", "passivity", "--out", str(t / "a_file" / "x.gif")], "a_file"),
    ("figures", lambda t: ["--only", "gif", "--gif-out", "/sys/x.gif"], "/sys"),
    ("run-jobs", lambda t: ["--spec", str(write_spec(t)), "--root", "/proc/softpvtol_runs"], "/proc"),
    ("run-jobs", lambda t: ["--spec", str(write_spec(t)), "--root", str(t / "a_file" / "runs")], "a_file"),
    ("leaderboard", lambda t: ["--from-json", "--json", str(REPO / "results/leaderboard.json"),
                               "--markdown", "/sys/l.md", "--chart", str(t / "l.png")], "/sys"),
    ("passivity-metrics", lambda t: ["--json", "/proc/p.json", "--episodes", "1"],
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
    line = one_error_line(capsys.readouterr().err)
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
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith("softpvtol train: error: cannot write /data/run/checkpoint.safetensors")
    assert words in line, line


def _dev_full_for_temporary_files(monkeypatch):
    """``open`` of the atomic writers gives /dev/full for their temporary files: the write fails with ENOSPC and
    an OSError without a file name, as on a full disk."""
    from softpvtol_gym.baselines.util import atomic

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    real_open = open

    def full_open(path, mode="r", *a, **k):
        return real_open("/dev/full" if "w" in mode and str(path).endswith(".tmp") else path, mode, *a, **k)

    monkeypatch.setattr(atomic, "open", full_open, raising=False)


def test_a_disk_full_met_while_writing_names_the_file_exit_74(tmp_path, monkeypatch, capsys):
    from softpvtol_gym.baselines.util.atomic import atomic_write_text

    _dev_full_for_temporary_files(monkeypatch)
    out = tmp_path / "result.json"

    def body(argv, layout, prog):
        atomic_write_text(out, "{}")
        return 0

    with pytest.raises(SystemExit) as exc:
        command_main("train.py", body, "test")([], prog="softpvtol train")
    assert exc.value.code == EXIT_IO_ERROR
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"softpvtol train: error: cannot write {out}: no space left") and "disk full" in line, line
    assert list(tmp_path.iterdir()) == []


def test_render_gif_on_a_full_disk_ends_before_rendering_naming_the_gif(tmp_path, monkeypatch, capsys):
    """The output check writes a little: a full disk is found before the episode renders (exit 74, one line)."""
    from softpvtol_gym.baselines.cli import run_command
    from softpvtol_gym.baselines.commands import render_gif

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    probe = tmp_path / "probe"

    def full_probe(directory):
        probe.write_bytes(b"")
        return os.open("/dev/full", os.O_WRONLY), str(probe)

    def reached(*a, **k):
        raise AssertionError("rendering started before the disk was found full")

    monkeypatch.setattr(args_mod, "_probe_file", full_probe)
    monkeypatch.setattr(render_gif, "make_policy_env", reached)
    monkeypatch.setattr(render_gif, "render_frames", reached)
    out = tmp_path / "x.gif"
    with pytest.raises(SystemExit) as exc:
        run_command("render-gif", ["--policy", "passivity", "--out", str(out)])
    assert exc.value.code == EXIT_IO_ERROR
    line = one_error_line(capsys.readouterr().err)
    assert f"cannot write {out}: no space left on the device (disk full)" in line, line
    assert list(tmp_path.iterdir()) == []


def test_a_job_that_meets_a_full_disk_is_reported_naming_the_file(tmp_path, capsys):
    from concurrent.futures import ThreadPoolExecutor

    target = tmp_path / "runs" / "full" / "eval.json"

    def full_entry(job, root, reevaluate=False, token=None, base=None):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    (tmp_path / "runs").mkdir()
    with ThreadPoolExecutor(1) as ex, pytest.raises(ConfigError, match="1 of 1 jobs failed"):
        run_jobs([StubJob("full")], ex, tmp_path / "runs", progress=False, rerun="softpvtol run-jobs", entry=full_entry)
    (failed,) = [line for line in capsys.readouterr().err.splitlines() if line.startswith("[failed]")]
    assert failed.startswith(f"[failed] full: cannot write {target}: no space left on the device (disk full)"), failed


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
        leaderboard.main(["--from-json", "--json", str(REPO / "results/leaderboard.json"),
                          "--markdown", str(md), "--chart", str(png)], prog="leaderboard")
    assert exc.value.code == EXIT_IO_ERROR
    line = one_error_line(capsys.readouterr().err)
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
    spec = write_spec(tmp)
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
    line = one_error_line(capsys.readouterr().err)
    assert str(path) in line and words in line, line
    assert sorted(p.name for p in out.iterdir()) == ["leaderboard.md"] and md.read_text() == "the committed page"


def test_leaderboard_from_json_refuses_nan_anywhere(tmp_path, capsys):
    from softpvtol_gym.baselines.commands import leaderboard

    data = json.loads((REPO / "results/leaderboard.json").read_text())
    data["cells"][0]["summary"]["mean_return"] = float("nan")
    src = tmp_path / "l.json"
    src.write_text(json.dumps(data))
    with pytest.raises(SystemExit) as exc:
        leaderboard.main(["--from-json", "--json", str(src), "--markdown", str(tmp_path / "l.md"),
                          "--chart", str(tmp_path / "l.png"), "--force"], prog="leaderboard")
    assert exc.value.code == 2
    line = one_error_line(capsys.readouterr().err)
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
