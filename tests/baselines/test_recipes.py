"""Training-only env options, the starting-error curriculum, training recipes (train.py
--recipe, leaderboard cells with a recipe) and the ablation table."""

from __future__ import annotations

import json

import pytest
import yaml

from softpvtol_gym.baselines.commands.train import build_parser, make_config
from softpvtol_gym.baselines.commands.train import main as train_main
from softpvtol_gym.baselines.config.hyperparams import TRAINING_ENV_OPTION_KEYS, parse_env_options
from softpvtol_gym.baselines.config.recipes import (
    RECIPES_FILE,
    load_recipe,
    load_recipes,
    recipe_config_fields,
    recipe_hyperparams,
    validate_recipe,
)
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.jobs import Job, load_jobs
from softpvtol_gym.baselines.leaderboard.spec import validate_spec
from softpvtol_gym.baselines.training.models import make_env
from tests.conftest import TINY, UP

PRECISE = {"precision_reward_weight": 1.0, "precision_reward_scale": 0.01, "action_rate_penalty": 0.1}


# ------------------------------------------------------------------------------ training-only options
def test_training_options_reach_the_training_env_only():
    c = RunConfig(task="track_random", train_env_options={**PRECISE, "start_distribution": "wide"},
                  env_options={"observe_error_integral": True})
    assert {k: c.env_kwargs()[k] for k in PRECISE} == PRECISE and c.env_kwargs()["start_distribution"] == "wide"
    assert not set(TRAINING_ENV_OPTION_KEYS) & set(c.eval_env_kwargs())
    assert c.eval_env_kwargs()["observe_error_integral"] is True
    env = make_env(c, 2)
    assert env.config.precision_reward_weight == 1.0 and env.config.start_distribution == "wide"
    assert env.config.extra_reward_terms == ("precision", "action_rate")


@pytest.mark.parametrize("kwargs, message", [
    ({"train_env_options": {"residual_scale": 0.4}},
     r"unknown training env option 'residual_scale' \(--train-env\).*pass it as --env"),
    ({"env_options": {"precision_reward_weight": 1.0}},
     r"unknown env option 'precision_reward_weight' \(--env\).*pass it as --train-env"),
    ({"train_env_options": {"precision_reward_weight": -1.0}}, "training env option precision_reward_weight: "),
    ({"train_env_options": {"start_distribution": "everywhere"}}, "training env option start_distribution: "),
    ({"train_env_options": [("action_rate_penalty", 1.0)]}, "train_env_options must be a mapping"),
    ({"action_mode": "actuators", "env_options": {"residual_gate": 0.1}}, "residual action mode only"),
    ({"start_error_curriculum": [0.2]}, r"start_error_curriculum must be \[s0, ramp_steps\]"),
    ({"start_error_curriculum": [-0.1, 1000]}, "start_error_curriculum must be"),
    ({"start_error_curriculum": [0.2, 0]}, "start_error_curriculum must be"),
    ({"start_error_curriculum": [0.2, 1.5]}, "start_error_curriculum must be"),
    ({"start_error_curriculum": (0.2, 100)}, "start_error_curriculum must be"),
])
def test_bad_training_options_are_config_errors(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        RunConfig(**kwargs)


def test_the_error_integral_observation_is_an_option_of_every_mode():
    c = RunConfig(action_mode="actuators", env_options={"observe_error_integral": True})
    assert make_env(c, 1).observation_space.shape == (21,)


def test_parse_training_options_names_the_flag():
    assert parse_env_options(["precision_reward_weight=2", "start_distribution=wide"], TRAINING_ENV_OPTION_KEYS,
                             "--train-env") == {"precision_reward_weight": 2, "start_distribution": "wide"}
    with pytest.raises(ConfigError, match=r"\(--train-env\) \(residual_gate belongs to --env\)"):
        parse_env_options(["residual_gate=0.1"], TRAINING_ENV_OPTION_KEYS, "--train-env")
    with pytest.raises(ConfigError, match=r"\(--env\) \(action_rate_penalty belongs to --train-env\)"):
        parse_env_options(["action_rate_penalty=0.1"])


def test_curriculum_ramps_linearly_to_the_runs_scale():
    c = RunConfig(start_error_curriculum=[0.2, 1000])
    assert [c.start_error_scale_at(s) for s in (0, 500, 1000, 5000)] == pytest.approx([0.2, 0.6, 1.0, 1.0])
    c = RunConfig(start_error_curriculum=[0.0, 100], train_env_options={"start_error_scale": 2.0})
    assert [c.start_error_scale_at(s) for s in (0, 50, 100)] == pytest.approx([0.0, 1.0, 2.0])
    assert RunConfig(train_env_options={"start_error_scale": 0.5}).start_error_scale_at(10) == 0.5


def test_saved_configs_without_the_new_fields_load_without_aids(tmp_path):
    c = RunConfig(train_env_options=dict(PRECISE), start_error_curriculum=[0.5, 200])
    path = tmp_path / "config.yaml"
    c.save(path)
    assert RunConfig.load(path) == c
    legacy = c.to_dict()
    del legacy["train_env_options"], legacy["start_error_curriculum"]
    path.write_text(yaml.safe_dump(legacy))
    old = RunConfig.load(path)
    assert old.train_env_options == {} and old.start_error_curriculum is None


def test_a_run_saved_without_a_recorded_recipe_resumes_without_recipe(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    legacy = RunConfig(n_envs=2, hyperparams={"n_envs": 2}).to_dict()
    del legacy["recipe"]
    (out / "config.yaml").write_text(yaml.safe_dump(legacy))
    assert RunConfig.load(out / "config.yaml").recipe is None
    ap = build_parser()
    config, _ = make_config(ap.parse_args(["--out", str(out), "--resume"]), ap)
    assert config.recipe is None
    with pytest.raises(ConfigError, match="records no recipe .*resume without --recipe"):
        make_config(ap.parse_args(["--out", str(out), "--resume", "--recipe", "residual-precise"]), ap)


# ------------------------------------------------------------------------------------------ recipes
def test_every_shipped_recipe_builds_a_valid_run():
    recipes = load_recipes()
    assert {"residual-integral", "residual-precise", "residual-precise-wide", "actuators-wide"} <= set(recipes)
    for name, r in recipes.items():
        c = RunConfig(**recipe_config_fields(r), hyperparams=recipe_hyperparams(r), task="track_random")
        assert c.action_mode == r["action_mode"] and c.env_options == r["env_options"], name
    precise = load_recipe("residual-precise")
    assert precise["controller_loop"] == "integral" and precise["env_options"]["observe_error_integral"] is True
    assert recipe_hyperparams(load_recipe("actuators-wide"))["learning_rate"] == 1.0e-3
    with pytest.raises(ConfigError, match=r"no recipe 'fastest'.*recipes: \["):
        load_recipe("fastest")


@pytest.mark.parametrize("entry, message", [
    ({"algo": "ppo", "action_mode": "residual"}, r"lacks the keys \['description'\]"),
    ({"description": "x", "algo": "a2c", "action_mode": "residual"}, "algo must be one of"),
    ({"description": "x", "algo": "ppo", "action_mode": "joints"}, "action_mode must be one of"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "controller_loop": "pid"},
     "controller_loop must be one of"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "env_options": {"precision_reward_weight": 1}},
     "env_options must be a mapping with keys among"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "hp": "n_epochs=5"}, "hp must be a list"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "seeds": [1]}, r"unknown keys \['seeds'\]"),
    ({"description": " ", "algo": "ppo", "action_mode": "residual"}, "description must be a non-empty string"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "eval_freq": 0}, "eval_freq must be a positive"),
    ({"description": "x", "algo": "ppo", "action_mode": "residual", "eval_freq": True}, "eval_freq must be a positive"),
])
def test_bad_recipes_are_config_errors_naming_the_key(entry, message):
    with pytest.raises(ConfigError, match=message):
        validate_recipe("mine", entry, "recipe 'mine'")
    with pytest.raises(ConfigError, match="name"):
        validate_recipe(f"{UP}/x", {"description": "x", "algo": "ppo", "action_mode": "residual"}, "recipe")


def test_train_recipe_sets_the_run_and_the_command_line_changes_it(tmp_path):
    ap = build_parser()
    config, out = make_config(ap.parse_args(["--recipe", "residual-precise", "--task", "track_random",
                                             "--hp", "n_epochs=3", "--train-env", "action_rate_penalty=0.5"]), ap)
    r = load_recipe("residual-precise")
    assert config.controller_loop == "integral" and config.env_options == r["env_options"]
    assert config.train_env_options == {**r["train_env_options"], "action_rate_penalty": 0.5}
    assert config.hyperparams["n_epochs"] == 3 and config.overrides == ["n_epochs=3"]
    assert str(out).startswith("runs/residual-precise_track_random_nominal_s0")
    config, _ = make_config(ap.parse_args(["--recipe", "actuators-wide", "--start-error-curriculum", "0.5,1000"]), ap)
    assert config.action_mode == "actuators" and config.start_error_curriculum == [0.5, 1000]
    assert config.overrides == ["learning_rate=1.0e-3"] and config.hyperparams["learning_rate"] == 1.0e-3
    # a recipe's evaluation period, which --eval-freq overrides; the others keep train.py's default
    assert make_config(ap.parse_args(["--recipe", "residual-fast"]), ap)[0].eval_freq == 250_000
    assert make_config(ap.parse_args(["--recipe", "residual-fast", "--eval-freq", "1000"]), ap)[0].eval_freq == 1000
    assert make_config(ap.parse_args(["--recipe", "residual-precise"]), ap)[0].eval_freq == 50_000
    for argv in (["--recipe", "actuators-wide", "--action-mode", "residual"], ["--start-error-curriculum", "0.5"],
                 ["--start-error-curriculum", "a,b"], ["--train-env", "residual_gate=0.1"]):
        with pytest.raises((SystemExit, ConfigError)):
            make_config(ap.parse_args(argv), ap)


def test_the_fast_recipe_trains_with_fused_adam_and_resumes(tmp_path):
    """residual-fast: its hyperparameters, one rollout of 128 x 128 steps trained with torch's
    fused Adam, and a resumed run that continues with the same optimizer."""
    from softpvtol_gym.baselines.checkpoints.load import load_folder

    hp = recipe_hyperparams(load_recipe("residual-fast"))
    assert (hp["n_envs"], hp["n_steps"], hp["batch_size"], hp["n_epochs"]) == (128, 128, 512, 3)
    assert hp["learning_rate"] == "lin_5e-3" and hp["n_timesteps"] == 1_000_000
    out = tmp_path / "run"
    args = ["--recipe", "residual-fast", "--task", "track_random", "--eval-freq", "16384", "--eval-episodes", "1",
            "--checkpoint-freq", "16384", "--out", str(out)]
    assert train_main([*args, "--timesteps", "16384"]) == 0
    model, _, _, _ = load_folder(out)
    assert model.policy.optimizer.param_groups[0]["fused"] is True
    assert model.num_timesteps == 16384
    assert train_main([*args, "--timesteps", "32768", "--resume"]) == 0
    resumed, _, _, _ = load_folder(out)
    assert resumed.num_timesteps == 32768 and resumed.policy.optimizer.param_groups[0]["fused"] is True
    # Adam's step count went on from the checkpoint: 3 epochs x 32 mini-batches per rollout
    steps = {float(s["step"]) for s in resumed.policy.optimizer.state.values()}
    assert {float(s["step"]) for s in model.policy.optimizer.state.values()} == {96.0} and steps == {192.0}


def test_a_torch_without_fused_cpu_adam_is_a_config_error_naming_the_fix(monkeypatch):
    import torch

    from softpvtol_gym.baselines.training.models import build_model

    def refuse(self, *args, **kwargs):  # what torch < 2.4 raises for fused=True on CPU tensors
        raise RuntimeError("`fused=True` requires all the params to be floating point Tensors of supported devices: "
                           "['cuda']")

    monkeypatch.setattr(torch.optim.Adam, "__init__", refuse)
    r = load_recipe("residual-fast")
    config = RunConfig(**recipe_config_fields(r), hyperparams=recipe_hyperparams(r), task="track_random", n_envs=2)
    with pytest.raises(ConfigError, match=r"optimizer_kwargs=dict\(fused=True\), which needs torch >= 2.4"):
        build_model(config, make_env(config))


def test_a_recipe_run_trains_with_its_aids_and_curriculum_and_evaluates_without_them(tmp_path):
    out = tmp_path / "run"
    assert train_main(["--recipe", "residual-precise-wide", "--task", "track_random", "--timesteps", "256", *TINY,
                       "--start-error-curriculum", "0.25,1000", "--out", str(out)]) == 0
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert saved["recipe"] == "residual-precise-wide"
    assert saved["train_env_options"]["start_distribution"] == "wide"
    assert saved["start_error_curriculum"] == [0.25, 1000]
    result = json.loads((out / "result.json").read_text())
    assert result["config"]["controller_loop"] == "integral"
    # the evaluation's episodes have the task's reward: its return is the env's without the aids
    from softpvtol_gym.baselines.evaluation import EVAL_SEED_OFFSET, run_episodes, summarize
    from softpvtol_gym.baselines.training.policy import LearnedPolicy

    policy, config = LearnedPolicy.load(out)
    kw = config.eval_env_kwargs()
    assert "precision_reward_weight" not in kw and kw["residual_gate"] == 0.05
    assert result["ppo"]["summary"] == summarize(run_episodes(policy, "residual", "track_random", "nominal", 1,
                                                              EVAL_SEED_OFFSET, env_kwargs=kw))


def test_the_curriculum_sets_the_scale_of_the_training_envs_resets():
    from softpvtol_gym.baselines.training.loop import _curriculum_callback, _set_start_error_scale

    c = RunConfig(task="track_random", start_error_curriculum=[0.2, 1000], n_envs=2)
    env = make_env(c, 2)
    _set_start_error_scale(env, c.start_error_scale_at(500))
    assert float(env.venv.sim.start_error_scale) == pytest.approx(0.6)
    cb = _curriculum_callback(c)

    class Model:
        num_timesteps = 2000

        logger = type("L", (), {"record": lambda *a: None})()

        def get_env(self):
            return env

    cb.model = Model()
    cb._on_rollout_start()
    assert float(env.venv.sim.start_error_scale) == 1.0


# ------------------------------------------------------------------------------------ the leaderboard
SPEC = {"evaluation": {"episodes": 2, "seed": 1000000, "tiers": ["nominal"]}, "tasks": ["track_random"],
        "trained": [], "seeds": [0]}


def _spec(*cells):
    return {**SPEC, "trained": [dict(c) for c in cells]}


CELL = {"action_mode": "residual", "task": "track_random", "tier": "hard", "timesteps": 1000}


def test_spec_cells_with_a_recipe_are_checked_and_named_by_it(tmp_path):
    spec = _spec(CELL, {**CELL, "recipe": "residual-precise"}, {**CELL, "recipe": "residual-integral"})
    validate_spec(spec)
    path = tmp_path / "spec.yml"
    path.write_text(yaml.safe_dump(spec))
    names = [j.name for j in load_jobs(path)]
    assert names == ["ppo_residual_track_random_hard/seed_0", "ppo-residual-precise_track_random_hard/seed_0",
                     "ppo-residual-integral_track_random_hard/seed_0"]
    with pytest.raises(ConfigError, match=r"trained\[1\].recipe: no recipe 'nope'"):
        validate_spec(_spec(CELL, {**CELL, "recipe": "nope"}))
    with pytest.raises(ConfigError, match="its recipe 'actuators-wide' trains the 'actuators' mode"):
        validate_spec(_spec({**CELL, "recipe": "actuators-wide"}))
    with pytest.raises(ConfigError, match="repeats the cell"):
        validate_spec(_spec({**CELL, "recipe": "residual-precise"}, {**CELL, "recipe": "residual-precise"}))
    with pytest.raises(ConfigError, match="hp"):
        validate_spec(_spec({**CELL, "recipe": "residual-precise", "hp": ["n_epochs=-1"]}))
    with pytest.raises(ConfigError):
        _ = Job(policy="ppo", action_mode="residual", task="track_random", train_tier="hard", seed=0, eval_tiers=(),
                eval_episodes=1, eval_seed=1000000, recipe=f"{UP}/up").name


def test_the_shipped_recipes_file_is_the_one_the_docs_name():
    assert RECIPES_FILE.name == "recipes.yml" and RECIPES_FILE.parent.name == "hyperparams"


# ------------------------------------------------------------------------------------------ ablation
def test_the_committed_ablation_table_is_generated_from_its_json():
    from softpvtol_gym.baselines.commands.ablation import BLOCK
    from softpvtol_gym.baselines.leaderboard.ablation import render_markdown
    from softpvtol_gym.baselines.util.blocks import read_block
    from tests.conftest import LAYOUT

    data = json.loads((LAYOUT.results / "ablation.json").read_text())
    assert read_block(*BLOCK, LAYOUT.doc("baselines.md")) == render_markdown(data).strip()
    spec = yaml.safe_load((LAYOUT.root / "baselines" / "ablation.yml").read_text())
    recipes = [r["recipe"] for r in data["recipes"]]
    # the reference row, every recipe of the spec in its order, then the leaderboard's recipe cell
    assert recipes[0] is None and recipes[1:1 + len(spec["trained"])] == [c["recipe"] for c in spec["trained"]]
    assert recipes[-1] == "residual-tracking"
    for rec in data["recipes"]:
        assert rec["seeds"] == spec["seeds"], rec["label"]
        assert {(r["task"], r["tier"]) for r in rec["rows"]} == {(t, tier) for t in spec["tasks"]
                                                                 for tier in spec["evaluation"]["tiers"]}
        assert all(r["runs"] == len(spec["seeds"]) and r["episodes"] == 20 for r in rec["rows"])


def test_the_ablation_command_refuses_bad_input_in_one_line(tmp_path, capsys):
    from softpvtol_gym.baselines.cli import run_command
    from softpvtol_gym.baselines.util.paths import Layout

    layout = Layout(results=tmp_path)
    cases = [(["--root", str(tmp_path / "none")], "--root"),
             (["--from-json", "--json", str(tmp_path / "none.json")], "is not a file"),
             (["--from-json", "--json", str(tmp_path / "bad.json")], "is not an ablation JSON")]
    (tmp_path / "bad.json").write_text('{"tasks": 1}')
    for argv, words in cases:
        with pytest.raises(SystemExit) as exc:
            run_command("ablation", argv, layout=layout, prog="ablation.py")
        err = capsys.readouterr().err
        assert exc.value.code == 2 and words in err and err.count("\n") <= 2, err


def _ablation_layout(tmp_path):
    """A layout whose docs page holds the ablation block, and a copy of the committed ablation JSON."""
    from softpvtol_gym.baselines.commands.ablation import BLOCK
    from softpvtol_gym.baselines.util.blocks import markers
    from softpvtol_gym.baselines.util.paths import Layout
    from tests.conftest import LAYOUT

    (tmp_path / "docs").mkdir()
    start, end = markers(*BLOCK)
    page = tmp_path / "docs" / "baselines.md"
    page.write_text(f"# Baselines\n\n{start}\nold table\n{end}\n")
    src = tmp_path / "ablation.json"
    src.write_text((LAYOUT.results / "ablation.json").read_text())
    return Layout(results=tmp_path / "results", root=tmp_path, docs=tmp_path / "docs"), page, src


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "1e400"])
def test_ablation_from_json_refuses_a_non_finite_value_and_writes_nothing(literal, tmp_path, capsys):
    from softpvtol_gym.baselines.cli import run_command

    layout, page, src = _ablation_layout(tmp_path)
    data = json.loads(src.read_text())
    data["recipes"][1]["rows"][0]["rms_position_error_steady_iqm"] = "PLACEHOLDER"
    src.write_text(json.dumps(data).replace('"PLACEHOLDER"', literal))
    before = page.read_text()
    with pytest.raises(SystemExit) as exc:
        run_command("ablation", ["--from-json", "--json", str(src)], layout=layout, prog="ablation.py")
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1, err
    assert "recipes[1].rows[0].rms_position_error_steady_iqm is not a finite number" in err and str(src) in err, err
    assert page.read_text() == before


def test_ablation_from_json_says_it_wrote_the_table_only(tmp_path, capsys):
    from softpvtol_gym.baselines.cli import run_command

    layout, page, src = _ablation_layout(tmp_path)
    before = src.read_bytes()
    assert run_command("ablation", ["--from-json", "--json", str(src)], layout=layout, prog="ablation.py") == 0
    out = capsys.readouterr().out
    assert out.strip() == f"wrote the table in {page}", out
    assert src.read_bytes() == before and "old table" not in page.read_text()


def test_the_ablation_json_records_its_spec_relative_to_the_layout_root(tmp_path, monkeypatch, capsys):
    from softpvtol_gym.baselines.cli import run_command
    from softpvtol_gym.baselines.commands import ablation
    from tests.conftest import LAYOUT

    layout, _, _ = _ablation_layout(tmp_path)
    spec = tmp_path / "baselines" / "ablation.yml"
    spec.parent.mkdir()
    spec.write_text("the spec\n")
    for folder in ("runs", "leaderboard_runs"):
        (tmp_path / folder).mkdir()
    # the real build records the spec path it was given; the runs it would score are not needed here
    committed = json.loads((LAYOUT.results / "ablation.json").read_text())
    monkeypatch.setattr(ablation, "build", lambda spec_path, *a: {**committed, "spec": str(spec_path)})
    out = tmp_path / "results" / "ablation.json"
    assert run_command("ablation", ["--spec", str(spec.resolve()), "--root", str(tmp_path / "runs"),
                                    "--leaderboard-root", str(tmp_path / "leaderboard_runs"), "--json", str(out)],
                       layout=layout, prog="ablation.py") == 0
    assert json.loads(out.read_text())["spec"] == "baselines/ablation.yml"
    assert f"wrote {out} and the table in" in capsys.readouterr().out


def test_the_committed_ablation_json_holds_no_absolute_path():
    from tests.conftest import LAYOUT

    data = json.loads((LAYOUT.results / "ablation.json").read_text())
    assert data["spec"] == "baselines/ablation.yml"
