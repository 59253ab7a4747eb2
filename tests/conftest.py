"""Shared fixtures: a tiny trained run (in the safe checkpoint format) and a process holding a lock."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: ".." for the path-traversal cases: built, so that no file of the project names a path that climbs
UP = os.pardir
sys.path.insert(0, str(ROOT / "baselines"))  # the checkout's layout (baselines/_clone.py), as its scripts see it
from _clone import LAYOUT, unpack_results  # noqa: E402

# the committed results are archives (results/archive/): unpacked before any test module reads them
unpack_results()

#: the committed results of the checkout, where its scripts write them
RESULTS = LAYOUT.results
RUNS_DIR = LAYOUT.runs
LEADERBOARD_JSON = RESULTS / "leaderboard.json"
#: 4 envs x 64 steps per rollout, a checkpoint every rollout: 512 steps train in a few seconds
TINY = ["--n-envs", "4", "--hp", "n_steps=64", "--hp", "batch_size=64", "--hp", "n_epochs=2", "--eval-episodes", "1",
        "--checkpoint-freq", "256", "--eval-freq", "1024", "--no-progress-bar"]


def _numba_environment() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k.startswith("NUMBA_")}


@pytest.fixture(autouse=True)
def numba_environment_is_left_as_found():
    """No test leaves a NUMBA_* variable changed in the test process: numba would reload its configuration at the
    next compile, drop the package's cache directory, and the later tests of the worker would see another
    configuration (set child processes' variables around their start only, or use ``monkeypatch.setenv``)."""
    before = _numba_environment()
    yield
    after = _numba_environment()
    assert after == before, f"the test changed numba's environment variables: {before} -> {after}"


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """A finished 512-step PPO run (residual / hover / nominal) with checkpoints at 256 and 512. Read-only:
    copy it (:func:`copy_run`) before changing anything."""
    from filelock import FileLock

    from softpvtol_gym.baselines.commands.train import main

    # under pytest-xdist every worker has its own base temp folder inside one shared parent: the first worker to
    # get here trains the run there, the others wait for it and read it
    shared = tmp_path_factory.getbasetemp().parent if "PYTEST_XDIST_WORKER" in os.environ else \
        tmp_path_factory.getbasetemp()
    out = shared / "tiny_run" / "run"
    with FileLock(str(shared / "tiny_run.lock")):
        if not (out / "checkpoint.json").is_file():
            shutil.rmtree(out.parent, ignore_errors=True)  # a run left half-written by an interrupted session
            out.parent.mkdir()
            assert main(["--timesteps", "512", *TINY, "--out", str(out)]) == 0
    return out


def copy_run(run: Path, dest: Path) -> Path:
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns(".softpvtol.lock*", "tb"))
    return dest


def rewrite_manifest(folder: Path) -> None:
    """Make ``checkpoint.json`` match the folder's files again (what an attacker who edits a checkpoint can
    always do: the manifest guards against corruption, not against a forger)."""
    import hashlib

    path = folder / "checkpoint.json"
    manifest = json.loads(path.read_text())
    files = {}
    for name in manifest["files"]:
        if (folder / name).is_file():
            data = (folder / name).read_bytes()
            files[name] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    manifest["files"] = files
    path.write_text(json.dumps(manifest))


@pytest.fixture
def lock_holder():
    """``lock_holder(directory)``: a separate process holds ``directory``'s lock until the test ends."""
    procs = []

    def hold(directory: Path) -> subprocess.Popen:
        code = ("import sys, time; from softpvtol_gym.baselines.util.locks import DirectoryLock; "
                f"DirectoryLock({str(directory)!r}, 'directory').acquire(); print('held', flush=True); "
                "sys.stdin.read()")
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                text=True, env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
        assert proc.stdout.readline().strip() == "held"
        procs.append(proc)
        return proc

    yield hold
    for proc in procs:
        proc.stdin.close()
        proc.wait(timeout=30)
