"""Bring your own policy: ``softpvtol score --policy MODULE:FACTORY`` and its library form (``score``).

A factory from a module outside the package (a dotted module importable from the current directory, or a path to
a .py file) is scored on the leaderboard's own test episodes with its statistics, and ranked among the committed
entries; every bad spec or bad policy is one line saying what was received and what is expected."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.summary import SUMMARY_FILE
from softpvtol_gym.baselines.user_policy import as_policy, load_factory
from softpvtol_gym.envs.vector import SoftPVTOLVectorEnv
from tests.conftest import LEADERBOARD_JSON

MODULE = """
import numpy as np
from softpvtol_gym import PassivityPolicy

NOT_CALLABLE = 3


def passivity(env):
    return PassivityPolicy.from_env(env)


def plain(env):
    policy = PassivityPolicy.from_env(env)
    return lambda obs: policy.predict(obs)[0]


def short_actions(env):
    return lambda obs: np.zeros((len(obs), 3))


def nothing(env):
    return 42


def raises(env):
    def act(obs):
        raise RuntimeError("my controller diverged")
    return act


def exits(env):
    def act(obs):
        raise SystemExit(0)
    return act


def nan_actions(env):
    return lambda obs: np.full((len(obs), 4), np.nan)


def words(env):
    return lambda obs: "hover please"


def exits_on_build(env):
    raise SystemExit(0)
"""


@pytest.fixture()
def user_module(tmp_path, monkeypatch):
    """``my_controllers.py`` in a folder of its own, which is the current directory."""
    (tmp_path / "my_controllers.py").write_text(MODULE)
    monkeypatch.chdir(tmp_path)
    return tmp_path / "my_controllers.py"


def test_a_dotted_module_and_a_file_path_both_load(user_module):
    assert load_factory("my_controllers:passivity").__name__ == "passivity"
    assert load_factory(f"{user_module}:plain").__name__ == "plain"


@pytest.mark.parametrize("spec, message", [
    ("my_controllers", r"--policy must be MODULE:FACTORY .* got 'my_controllers'"),
    ("my_controllers:", r"--policy must be MODULE:FACTORY"),
    ("no_such_module_here:make", r"module 'no_such_module_here' not found \(it must be importable from the current "
                                 r"directory .*, or pass a path to a \.py file\)"),
    ("missing/controller.py:make", r"no Python file at missing/controller\.py"),
    ("my_controllers:absent", r"my_controllers has no attribute 'absent'"),
    ("my_controllers:NOT_CALLABLE", r"NOT_CALLABLE is a int, not callable"),
])
def test_a_bad_spec_is_one_clear_error(user_module, spec, message):
    with pytest.raises(ConfigError, match=message):
        load_factory(spec)


def test_a_bad_policy_is_refused_naming_what_it_returned():
    env = SoftPVTOLVectorEnv(num_envs=1, action_mode="actuators", task="hover")
    with pytest.raises(ConfigError, match=r"returned a int, which has no predict method and is not callable"):
        as_policy(42, env)
    policy = as_policy(lambda obs: np.zeros((len(obs), 3)), env)
    with pytest.raises(ConfigError, match=r"actions of shape \(2, 3\) for observations of shape \(2, \d+\); expected "
                                          r"\(2, 4\)"):
        policy.predict(np.zeros((2, env.single_observation_space.shape[0])))
    obs = np.zeros((2, env.single_observation_space.shape[0]))
    for make, message in (
            (lambda o: 1 / 0, r"the policy raised ZeroDivisionError: division by zero on observations of shape \(2, "),
            (lambda o: np.full((2, 4), np.inf), r"returned a non-finite action \(inf\)"),
            (lambda o: np.full((2, 4), np.nan), r"returned a non-finite action \(nan\)"),
            (lambda o: "up", r"returned str 'up' for observations of shape \(2, \d+\); expected real numbers"),
            (lambda o: np.ones((2, 4), bool), r"returned ndarray .*expected real numbers"),
            (lambda o: sys.exit(0), r"the policy called sys.exit\(0\) on observations")):
        with pytest.raises(ConfigError, match=message):
            as_policy(make, env).predict(obs)
    one = as_policy(lambda obs: np.ones(4), env)
    action, state = one.predict(np.zeros(env.single_observation_space.shape[0]))
    assert action.shape == (4,) and state is None


def test_score_uses_the_leaderboards_episodes_and_statistics_and_ranks_the_policy(user_module):
    """The passivity controller brought as a plain callable gets the committed passivity-bounded row's statistics
    on hover / nominal (the same seeded episodes, the same IQM), a per-robot compute, and a rank."""
    from softpvtol_gym.baselines.leaderboard.score import score

    result = score(load_factory("my_controllers:plain"), tasks=["hover"], tiers=["nominal"],
                   leaderboard=LEADERBOARD_JSON)
    (row,) = result["aggregates"]
    board = json.loads(LEADERBOARD_JSON.read_text())
    committed = next(r for r in board["aggregates"] if (r["task"], r["tier"], r["entry"]) == (
        "hover", "nominal", "passivity-bounded"))
    assert result["meta"]["episodes"] == board["meta"]["episodes"] and result["meta"]["test_seed"] == 1_000_000
    assert row["rms_position_error_iqm"] == pytest.approx(committed["rms_position_error_iqm"], rel=1e-9)
    assert row["compute_us_single"] > 0
    eps = result["episodes"]["hover"]["nominal"]
    assert len(eps) == 20 and {e["compute_us_single"] for e in eps} == {row["compute_us_single"]}
    ranks = {r["window"]: r for r in result["ranking"]}
    assert set(ranks) == {"whole", "transient", "steady", "final_5s"}
    here = [r for r in board["aggregates"] if (r["task"], r["tier"]) == ("hover", "nominal")]
    whole = ranks["whole"]
    assert whole["of"] == len(here) + 1
    assert whole["rank"] == 1 + sum(r["rms_position_error_iqm"] < row["rms_position_error_iqm"] for r in here)
    assert whole["best"]["rms_position_error_iqm"] == min(r["rms_position_error_iqm"] for r in here)


def test_the_command_scores_a_file_module_writes_json_and_refuses_bad_input(user_module, tmp_path, capsys):
    from softpvtol_gym.baselines.commands.score import main

    out = tmp_path / "mine.json"
    # in a directory of the user's own: ranked against the summary that ships with the package
    assert main(["--policy", f"{user_module}:passivity", "--task", "hover", "--tier", "wind", "--episodes", "2",
                 "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    shipped = json.loads(SUMMARY_FILE.read_text())["aggregates"]
    entries = sum((r["task"], r["tier"]) == ("hover", "wind") for r in shipped)
    assert "| hover | wind | RMS, last half |" in printed and f"of {entries + 1} |" in printed
    data = json.loads(out.read_text())
    assert len(data["episodes"]["hover"]["wind"]) == 2 and len(data["ranking"]) == 4
    for argv, message in ((["--policy", "my_controllers:nothing"], "returned a int, which has no predict"),
                          (["--policy", "my_controllers:short_actions"], "actions of shape (2, 3)"),
                          (["--policy", "my_controllers"], "--policy must be MODULE:FACTORY"),
                          (["--policy", "my_controllers:raises"], "the policy raised RuntimeError: my controller "
                                                                  "diverged on observations of shape (2,"),
                          (["--policy", "my_controllers:exits"], "the policy called sys.exit(0)"),
                          (["--policy", "my_controllers:exits_on_build"], "failed on hover/nominal: it called "
                                                                          "sys.exit(0)"),
                          (["--policy", "my_controllers:nan_actions"], "returned a non-finite action (nan)"),
                          (["--policy", "my_controllers:words"], "returned str 'hover please'"),
                          (["--policy", "my_controllers:passivity", "--tier", "nominal"],
                           "--tier nominal is given twice")):
        with pytest.raises(SystemExit) as exc:
            main([*argv, "--task", "hover", "--tier", "nominal", "--episodes", "2",
                  "--leaderboard", str(LEADERBOARD_JSON)])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_the_packaged_summary_is_the_committed_leaderboards_aggregates():
    from softpvtol_gym.baselines.leaderboard.stats import read_data
    from softpvtol_gym.baselines.leaderboard.summary import SUMMARY_FILE, summary_bytes

    board = json.loads(LEADERBOARD_JSON.read_text())
    assert SUMMARY_FILE.read_bytes() == summary_bytes(board)  # python baselines/leaderboard.py --from-json writes it
    summary = read_data(SUMMARY_FILE)
    assert summary["aggregates"] == board["aggregates"] and summary["cells"] == []
    assert SUMMARY_FILE.stat().st_size < 2_000_000
