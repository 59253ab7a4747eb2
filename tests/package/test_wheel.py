"""The built wheel, installed (not editable) into a fresh environment, runs
``softpvtol evaluate --policy passivity`` in a directory outside the checkout and writes its JSON there, and
``softpvtol score`` ranks a module of the user's own there against the leaderboard summary the wheel ships.

No download: the wheel is built without build isolation from a copy of the project (nothing is written into
the checkout), and the fresh venv finds the dependencies through a ``.pth`` line naming this interpreter's
site-packages. Python does not process ``.pth`` files inside a directory that a ``.pth`` line added, so this
interpreter's editable install of the checkout does not leak in (checked: ``softpvtol_gym.__file__`` lies in
the fresh venv).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _project_copy(dest: Path) -> Path:
    """The files a wheel is built from: the top-level files of the checkout and the package."""
    dest.mkdir()
    for path in ROOT.iterdir():
        if path.is_file() and not path.name.startswith("."):
            shutil.copy2(path, dest / path.name)
    shutil.copytree(ROOT / "softpvtol_gym", dest / "softpvtol_gym",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))
    return dest


def _run(args, **kwargs) -> subprocess.CompletedProcess:
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=1200, **kwargs)
    assert r.returncode == 0, (args, r.stdout[-3000:], r.stderr[-3000:])
    return r


@pytest.mark.slow
def test_installed_wheel_runs_softpvtol_evaluate_outside_the_checkout(tmp_path):
    source = _project_copy(tmp_path / "src")
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", wheels,
          source])
    (wheel,) = wheels.glob("softpvtol_gym-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert all(t.startswith("softpvtol") for t in tops), tops  # no top-level 'baselines' package
    assert "softpvtol_gym/baselines/data/leaderboard.yml" in names
    assert "softpvtol_gym/baselines/data/hyperparams/ppo.yml" in names
    assert "softpvtol_gym/baselines/data/leaderboard_summary.json" in names
    assert not [n for n in names if "/results/" in n]  # results are data of the checkout, not package contents

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (site / "outer_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", wheel])

    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = _run([python, "-c", "import softpvtol_gym; print(softpvtol_gym.__file__)"], cwd=work, env=env).stdout
    assert Path(where.strip()).is_relative_to(venv) and not Path(where.strip()).is_relative_to(ROOT), where

    softpvtol = venv / "bin" / "softpvtol"
    assert "passivity-metrics" in _run([softpvtol, "--help"], cwd=work, env=env).stdout
    r = _run([softpvtol, "evaluate", "--policy", "passivity", "--episodes", "1", "--json", "out/passivity.json"],
             cwd=work, env=env)
    report = json.loads((work / "out" / "passivity.json").read_text())
    assert report["summary"]["episodes"] == 1 and "passivity" in r.stdout
    (work / "mine.py").write_text("from softpvtol_gym import PassivityPolicy\n\n\ndef make(env):\n"
                                  "    return PassivityPolicy.from_env(env)\n")
    r = _run([softpvtol, "score", "--policy", "mine.py:make", "--task", "hover", "--tier", "nominal", "--episodes",
              "2"], cwd=work, env=env)
    assert "| hover | nominal | RMS, last half |" in r.stdout and " of " in r.stdout, r.stdout
    assert sorted(p.relative_to(work).as_posix() for p in work.rglob("*") if "__pycache__" not in p.parts) == [
        "mine.py", "out", "out/passivity.json"]
