"""train.py: a short run trains, saves and evaluates; bad input exits with code 2, nothing overwritten."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd=ROOT):
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_smoke_training_saves_and_evaluates(tmp_path):
    out = tmp_path / "run"
    r = run("--timesteps", "512", "--n-envs", "2", "--eval-episodes", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    assert (out / "model.zip").stat().st_size > 1000
    res = json.loads((out / "result.json").read_text())
    assert set(res) >= {"ppo", "passivity"} and res["passivity"]["episodes"] == 2
    assert "passivity" in r.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["--action-mode", "joystick"], "invalid choice"),
        (["--timesteps", "-5"], "--timesteps must be >= 1"),
        (["--task", "loop"], "invalid choice"),
    ],
)
def test_bad_cli_input_exits_2(args, message, tmp_path):
    r = run(*args, "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and message in r.stderr
    assert not (tmp_path / "x").exists()


def test_existing_output_is_not_overwritten(tmp_path):
    (tmp_path / "model.zip").write_bytes(b"keep")
    r = run("--out", str(tmp_path))
    assert r.returncode == 2 and "nothing was overwritten" in r.stderr
    assert (tmp_path / "model.zip").read_bytes() == b"keep"
