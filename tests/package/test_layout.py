"""The baselines library's layout (the layers of the whole package: test_layers.py). ``softpvtol_gym.baselines``
imports sit at module top (except the optional heavy extras, imported where used), no module is over 600 lines,
the env package does not import the baselines, the wheel installs only ``softpvtol*`` names, and the
``softpvtol`` console command lists every subcommand and answers ``--help`` for each."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from softpvtol_gym.baselines import cli

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "softpvtol_gym" / "baselines"
PREFIX = "softpvtol_gym.baselines"
#: imported inside functions on purpose: heavy or optional, named by the extras check when missing (the SB3
#: adapter and the zero-at-zero policy import stable-baselines3 and torch)
LAZY = ("torch", "stable_baselines3", "matplotlib", "ray", "rliable", "optuna", "PIL", "tqdm", "safetensors",
        "importlib.metadata", "softpvtol_gym.envs.sb3", "softpvtol_gym.baselines.training.zero_residual")


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def test_imports_sit_at_module_top_except_the_optional_extras():
    hidden = []
    for name, path in MODULES.items():
        for fn in ast.walk(ast.parse(path.read_text())):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, (ast.Import, ast.ImportFrom)):
                        mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                        hidden += [f"{name}:{node.lineno} {m}" for m in mods
                                   if not any(m == lazy or m.startswith(lazy + ".") for lazy in LAZY)]
    assert hidden == []


def test_subpackage_inits_import_nothing():
    """Importing softpvtol_gym.baselines.X.y runs X/__init__.py: it must not pull in the rest."""
    for name, path in MODULES.items():
        if path.name == "__init__.py":
            tree = ast.parse(path.read_text())
            assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], name


def test_no_module_is_over_600_lines():
    long = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > 600}
    assert long == {}


def test_every_module_imports():
    import importlib

    for name in MODULES:
        if not name.endswith("__main__"):
            importlib.import_module(name)


def test_the_env_package_does_not_import_the_baselines():
    code = "import sys, softpvtol_gym; print(any(m.startswith('softpvtol_gym.baselines') for m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr[-2000:]


def test_the_wheel_installs_softpvtol_names_and_the_console_command():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["scripts"] == {"softpvtol": "softpvtol_gym.baselines.cli:main"}
    include = project["tool"]["setuptools"]["packages"]["find"]["include"]
    assert include and all(p.startswith("softpvtol") for p in include)
    data = project["tool"]["setuptools"]["package-data"]["softpvtol_gym.baselines"]
    for pattern in data:
        assert list(PACKAGE.glob(pattern)), pattern
    assert not (ROOT / "baselines" / "__init__.py").exists()  # the checkout's scripts folder is no package


def test_the_library_does_not_know_the_checkout():
    """Only baselines/_clone.py (the checkout's scripts) locates the checkout; the library writes where its
    layout says (default: the current directory). Allowed: where ``softpvtol_gym`` itself is imported from
    (the Ray workers' PYTHONPATH), which is no checkout path."""
    offenders = [f"{name}: {line.strip()}" for name, path in MODULES.items()
                 for line in path.read_text().splitlines()
                 if ("__file__" in line or "REPO_ROOT" in line or "parents[" in line)
                 and "softpvtol_gym.__file__" not in line]
    assert offenders == []


# -------------------------------------------------------------------------------- the console command
def test_help_lists_every_subcommand(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in ("train", "evaluate", "export", "run-jobs", "leaderboard", "tune", "figures", "reproduce-paper",
                 "passivity-metrics"):
        assert name in cli.COMMANDS and f"  {name} " in out


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_each_subcommand_answers_help(name, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([name, "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: softpvtol {name}")


def test_an_unknown_subcommand_is_one_line_with_exit_2(capsys):
    assert cli.main(["evalute"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown subcommand 'evalute'" in err and "evaluate" in err
    assert cli.main([]) == 2


def test_bad_input_names_the_subcommand(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        cli.main(["evaluate", "--policy", "passivity", "--episodes", "0"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith("softpvtol evaluate: error: ") and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_python_dash_m_runs_the_command():
    r = subprocess.run([sys.executable, "-m", "softpvtol_gym.baselines", "--help"], cwd=ROOT, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and "passivity-metrics" in r.stdout, r.stderr[-2000:]


# -------------------------------------------------------------------------------- the checkout's scripts
SCRIPTS = sorted(p.name for p in (ROOT / "baselines").glob("*.py") if not p.name.startswith("_"))


def test_every_script_runs_a_subcommand():
    assert {cli.COMMANDS[c][1] for c in cli.COMMANDS} == {*SCRIPTS, "train.py"}


@pytest.mark.parametrize("script", ["train.py", *SCRIPTS])
def test_each_checkout_script_answers_help(script, capsys, monkeypatch):
    import runpy

    path = ROOT / script if script == "train.py" else ROOT / "baselines" / script
    monkeypatch.setattr(sys, "argv", [str(path), "--help"])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(path), run_name="__main__")
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: {script}")
    assert len(path.read_text().splitlines()) <= 20  # thin: the logic is in softpvtol_gym.baselines


def test_a_policy_given_by_hand_never_overwrites_the_leaderboard_pictures(tmp_path):
    """tracking_figures.py --checkpoint RUN: the default tracking plot and GIF are other files than the
    committed pictures of the leaderboard's policy (no command overwrites a committed file)."""
    from softpvtol_gym.baselines.commands.figures import _default_outputs, build_parser
    from tests.conftest import LAYOUT

    committed = build_parser(LAYOUT).parse_args([])
    _default_outputs(committed)
    assert committed.gif_out == LAYOUT.doc("best_policy_track_paper.gif")
    assert committed.tracking_out == LAYOUT.results / "tracking" / "track_paper.png"
    by_hand = build_parser(LAYOUT).parse_args(["--checkpoint", str(tmp_path)])
    _default_outputs(by_hand)
    assert by_hand.gif_out != committed.gif_out and by_hand.tracking_out != committed.tracking_out
    assert by_hand.curves_out == committed.curves_out  # the curves do not depend on the policy
    explicit = build_parser(LAYOUT).parse_args(["--checkpoint", str(tmp_path), "--gif-out", str(tmp_path / "a.gif")])
    _default_outputs(explicit)
    assert explicit.gif_out == tmp_path / "a.gif"


@pytest.mark.parametrize("script, argv, output", [
    ("passivity_metrics.py", ["--episodes", "2"], "passivity_metrics.json"),
    ("model_figures.py", ["--t-final", "1"], "model_figures.json"),
    ("reproduce_paper.py", ["--t-final", "5", "--no-plots"], "paper_reproduction/metrics.json"),
    ("tracking_figures.py", ["--only", "curves", "--curve-reference", "leaderboard"], "tracking/learning_curves.png"),
])
def test_a_run_with_other_settings_never_overwrites_a_committed_result(script, argv, output, capsys):
    """The default outputs of a checkout's script are committed results: a run with other settings than the
    defaults refuses to overwrite them (exit 2, one line, nothing written) unless --force or another path."""
    from tests.conftest import LAYOUT

    name = next(c for c, (_, s, _) in cli.COMMANDS.items() if s == script)
    committed = LAYOUT.results / output
    before = committed.read_bytes()
    with pytest.raises(SystemExit) as exc:
        cli.run_command(name, argv, layout=LAYOUT, prog=script)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith(f"{script}: error: ") and "--force" in err, err
    assert err.count("\n") == 1 and committed.read_bytes() == before
