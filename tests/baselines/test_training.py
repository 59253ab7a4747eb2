"""train.py / baselines training: smoke run, kill + exact resume, evaluation CLI, bad input (exit 2)."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from softpvtol_gym.baselines.commands.evaluate import main as evaluate_main
from softpvtol_gym.baselines.commands.train import main as train_main
from softpvtol_gym.baselines.config.hyperparams import algo_kwargs, apply_overrides, load_hyperparams, parse_dict_call
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
# a short configuration: 4 envs x 64 steps per rollout, checkpoints every rollout
SHORT = ["--n-envs", "4", "--hp", "n_steps=64", "--hp", "batch_size=64", "--hp", "n_epochs=2",
         "--eval-episodes", "1", "--checkpoint-freq", "256", "--eval-freq", "1024", "--no-progress-bar"]


def assert_exit_2(main, argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err, err[-2000:]


def run(script: str, *args, timeout=600):
    return subprocess.run([sys.executable, str(ROOT / script), *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


# ------------------------------------------------------------------------------------ config
@pytest.mark.parametrize("mode", ["residual", "virtual", "actuators"])
def test_every_action_mode_has_ppo_hyperparameters(mode):
    hp = load_hyperparams("ppo", mode)
    kwargs = algo_kwargs(hp)
    assert hp["n_envs"] >= 1 and hp["n_timesteps"] >= 1 and "n_envs" not in kwargs
    assert isinstance(kwargs["policy_kwargs"], dict)


def test_overrides_are_parsed_as_yaml_and_policy_kwargs_without_eval():
    hp = apply_overrides({"n_epochs": 10}, ["n_epochs=5", "learning_rate=1e-4", "normalize=false"])
    assert hp == {"n_epochs": 5, "learning_rate": 1e-4, "normalize": False}
    assert parse_dict_call("dict(log_std_init=-2.0, net_arch=dict(pi=[64, 64]))") == {
        "log_std_init": -2.0, "net_arch": {"pi": [64, 64]}}
    with pytest.raises(ConfigError, match="only hold"):
        parse_dict_call("dict(activation_fn=__import__('os').system('true'))")
    with pytest.raises(ConfigError, match="key=value"):
        apply_overrides({}, ["n_epochs"])


@pytest.mark.parametrize("field, value", [("timesteps", 0), ("seed", -1), ("action_mode", "joystick"),
                                          ("n_envs", 0), ("algo", "dqn")])
def test_run_config_rejects_bad_values(field, value):
    with pytest.raises(ConfigError, match=field if field != "algo" else "algo"):
        RunConfig(**{field: value})


def test_run_config_round_trips(tmp_path):
    cfg = RunConfig(action_mode="virtual", seed=3, hyperparams={"n_steps": 64}, overrides=["n_steps=64"])
    cfg.save(tmp_path / "c.yaml")
    assert RunConfig.load(tmp_path / "c.yaml") == cfg


# ------------------------------------------------------------------------------ train.py runs
@pytest.mark.slow  # train.py in a subprocess
def test_smoke_training_saves_checkpoints_and_compares_with_passivity(tmp_path):
    out = tmp_path / "run"
    r = run("train.py", "--timesteps", "1024", *SHORT, "--out", out)
    assert r.returncode == 0, r.stderr[-3000:]
    for name in ("model.safetensors", "model.json", "vecnormalize.json", "checkpoint.json", "config.yaml",
                 "result.json", "evaluations.json"):
        assert (out / name).stat().st_size > 0, name
    assert not list(out.rglob("*.pkl")) and not list(out.rglob("*.zip"))  # nothing pickle-based is written
    assert list((out / "tb").glob("PPO_*/events.out.tfevents.*"))
    ckpts = sorted(p.name for p in (out / "checkpoints").glob("step_*"))
    assert ckpts == ["step_0000000768", "step_0000001024"]  # every 256 steps and at the end, newest two kept
    assert (out / "checkpoints" / "latest").read_text() == "step_0000001024"
    res = json.loads((out / "result.json").read_text())
    assert res["config"]["overrides"][:3] == ["n_steps=64", "batch_size=64", "n_epochs=2"]
    assert res["config"]["hyperparams"]["n_steps"] == 64
    assert res["passivity"]["summary"]["episodes"] == 1 and len(res["ppo"]["episodes"]) == 1
    assert "passivity" in r.stdout and "ppo" in r.stdout


def test_the_passivity_episodes_run_before_training_so_nothing_compiles_between_it_and_the_table(tmp_path,
                                                                                                    monkeypatch):
    """softpvtol train evaluates the passivity controller before the first training step (its kernels compile
    then) and the trained policy after the last; a second call on the finished run evaluates nothing."""
    import softpvtol_gym.baselines.commands.train as command

    calls = []
    real_train, real_evaluate = command.train, command.evaluate
    monkeypatch.setattr(command, "train", lambda *a, **k: calls.append("train") or real_train(*a, **k))
    monkeypatch.setattr(command, "evaluate",
                        lambda policy, *a, **k: calls.append(type(policy).__name__) or real_evaluate(policy, *a, **k))
    out = tmp_path / "run"
    assert train_main(["--timesteps", "256", *SHORT, "--out", str(out)]) == 0
    assert calls == ["PassivityPolicy", "train", "LearnedPolicy"]
    calls.clear()
    assert train_main(["--timesteps", "256", *SHORT, "--out", str(out), "--resume"]) == 0
    assert calls == ["train"]  # a finished run with its result: nothing evaluated again


@pytest.mark.slow  # three train.py runs in subprocesses
def test_killed_run_resumes_bit_for_bit(tmp_path):
    """SIGKILL a run after a checkpoint; --resume finishes it with the same weights (and optimizer state,
    counters, last observation) as an uninterrupted run."""
    from safetensors.torch import load_file

    args = ["--timesteps", "4096", *SHORT]
    ref = run("train.py", *args, "--out", tmp_path / "ref")
    assert ref.returncode == 0, ref.stderr[-3000:]
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args, "--out", str(out)], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while not list((out / "checkpoints").glob("step_000000[1-3]*")) and proc.poll() is None:
        assert time.time() < deadline
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "checkpoint.json").exists(), "the run finished before it could be killed"
    r = run("train.py", *args, "--out", out, "--resume")
    assert r.returncode == 0, r.stderr[-3000:]
    a, b = load_file(tmp_path / "ref" / "model.safetensors"), load_file(out / "model.safetensors")
    assert sorted(a) == sorted(b) and any(k.startswith("policy.optimizer/") for k in a)
    for key in a:
        assert (a[key] == b[key]).all(), key
    assert [json.loads((d / "model.json").read_text())["counters"]["num_timesteps"] for d in (tmp_path / "ref", out)] \
        == [4096, 4096]
    steps = [e["step"] for e in json.loads((out / "evaluations.json").read_text())]
    assert steps == sorted(set(steps)) and steps[-1] == 4096


@pytest.mark.parametrize(
    "args, message",
    [
        (["--action-mode", "joystick"], "invalid choice"),
        (["--timesteps", "-5"], "--timesteps must be >= 1"),
        (["--task", "loop"], "invalid choice"),
        (["--hp", "n_epochs"], "key=value"),
        (["--seed", "-1"], "--seed must be in"),
        (["--resume"], "does not exist"),
        (["--hp", "n_epochs=5", "--hp", "n_epochs=6"], "--hp n_epochs is given twice (n_epochs=5, n_epochs=6)"),
        (["--env", "residual_scale=0.4", "--env", "residual_scale=0.5"], "--env residual_scale is given twice"),
        (["--bc-weight", "2"], "--bc-weight sets the imitation term, which needs --bc-teacher"),
        (["--bc-epochs", "2"], "--bc-epochs sets the imitation term"),
        (["--action-mode", "actuators", "--controller-loop", "integral"],
         "the run's action mode is actuators, which has none"),
        (["--action-mode", "virtual", "--controller-loop", "integral"], "the run's action mode is virtual"),
    ],
)
def test_bad_train_input_exits_2_and_writes_nothing(args, message, tmp_path, capsys):
    assert_exit_2(train_main, [*args, "--out", str(tmp_path / "x")], message, capsys)
    assert not (tmp_path / "x").exists()


def test_resume_refuses_a_run_whose_config_cannot_be_read(tmp_path, capsys):
    (tmp_path / "model.safetensors").write_bytes(b"keep")
    (tmp_path / "config.yaml").write_bytes(b"action_mode: actuators\ntask: caf\xe9\n")
    assert_exit_2(train_main, ["--resume", "--timesteps", "64", "--out", str(tmp_path)],
                  "has no readable config (cannot read run config", capsys)
    assert (tmp_path / "model.safetensors").read_bytes() == b"keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "model.safetensors"]


def test_an_empty_out_is_refused_not_the_current_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert_exit_2(train_main, ["--timesteps", "64", "--out", ""], "argument --out: expected a path, got ''", capsys)
    assert list(tmp_path.iterdir()) == []


def test_the_help_recipes_exist(capsys):
    from softpvtol_gym.baselines.commands import train as train_command
    from softpvtol_gym.baselines.config.recipes import load_recipe

    named = re.findall(r"--recipe ([\w-]+)", train_command.__doc__)
    assert named and all(load_recipe(name) for name in named)


def test_device_option(tmp_path, capsys):
    """--device auto|cpu|cuda: the policy's device (the env steps on the CPU); cuda without a GPU is an exit 2
    that says so, before anything is written."""
    import torch

    from softpvtol_gym.baselines.training.models import resolve_device

    assert resolve_device("cpu") == "cpu"
    assert resolve_device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ConfigError, match="device must be one of"):
        resolve_device("tpu")
    assert_exit_2(train_main, ["--device", "tpu", "--out", str(tmp_path / "x")], "invalid choice", capsys)
    if not torch.cuda.is_available():
        assert_exit_2(train_main, ["--device", "cuda", "--out", str(tmp_path / "x")],
                      "--device cuda: torch sees no CUDA GPU", capsys)
        assert not (tmp_path / "x").exists()
    out = tmp_path / "auto"
    assert train_main(["--device", "auto", "--timesteps", "256", *SHORT, "--out", str(out)]) == 0
    assert json.loads((out / "result.json").read_text())["device"] == resolve_device("auto")


#: what may differ between two identical runs: wall times, and TensorBoard's event files (named by time and host)
TIMING_KEYS = {"train_seconds", "wall_time", "seconds"}


def _without_timings(value):
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def test_two_identical_runs_write_identical_files(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    for out in runs:
        assert train_main(["--timesteps", "512", *SHORT, "--eval-freq", "256", "--out", str(out)]) == 0
    files = [sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file() and "tb" not in p.parts)
             for out in runs]
    assert files[0] == files[1] and any(p.name == "model.json" for p in files[0])
    for rel in files[0]:
        a, b = ((out / rel).read_bytes() for out in runs)
        if rel.name in ("evaluations.json", "result.json"):  # their wall times aside
            assert _without_timings(json.loads(a)) == _without_timings(json.loads(b)), rel
        else:
            assert a == b, rel


def test_existing_run_is_not_overwritten(tmp_path, capsys):
    (tmp_path / "model.zip").write_bytes(b"keep")  # even a run of the earlier, pickle-based format
    assert_exit_2(train_main, ["--timesteps", "256", *SHORT, "--out", str(tmp_path)], "nothing was overwritten", capsys)
    assert (tmp_path / "model.zip").read_bytes() == b"keep"


# ----------------------------------------------------------------------------- evaluate.py
def test_evaluate_cli_writes_episode_json(tmp_path, capsys):
    out = tmp_path / "e.json"
    assert evaluate_main(["--policy", "passivity", "--task", "hover", "--tier", "wind", "--episodes", "2",
                          "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["seed"] == 1_000_000 and len(data["episodes"]) == 2
    assert set(data["episodes"][0]) == {"return", "rms_position_error", "rms_attitude_error", "control_effort",
                                        "crashed", "length", "rms_position_error_transient",
                                        "rms_position_error_steady", "max_position_error_final_5s",
                                        "compute_us_per_step", "compute_us_per_step_p99", "compute_us_per_step_max",
                                        "fraction_within_1cm"}
    assert all(0 <= e["fraction_within_1cm"] <= 1 for e in data["episodes"])
    assert data["summary"]["episodes"] == 2 and 0 <= data["summary"]["crash_rate"] <= 1
    assert_exit_2(evaluate_main, ["--policy", "passivity", "--episodes", "2", "--json", str(out)], "exists", capsys)


def test_evaluate_refuses_a_repeated_mpc_option(capsys):
    assert_exit_2(evaluate_main, ["--policy", "mpc", "--mpc-option", "horizon=5", "--mpc-option", "horizon=6"],
                  "--mpc-option horizon is given twice (horizon=5, horizon=6); give it once", capsys)


@pytest.mark.parametrize("option", [["--controller-loop", "integral"], ["--allocation", "paper"]])
def test_evaluate_refuses_a_loop_option_for_an_actuator_checkpoint(option, capsys):
    run_dir = ROOT / "results/leaderboard_runs/distilled-integral-small_track_random_nominal/seed_0"
    assert_exit_2(evaluate_main, ["--policy", str(run_dir), "--episodes", "1", *option],
                  "acts on the actuators, so it would change nothing", capsys)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--policy", "no/such/checkpoint"], "does not exist"),
        (["--policy", "passivity", "--action-mode", "joystick"], "invalid choice"),
        (["--policy", "passivity", "--episodes", "0"], "--episodes must be >= 1"),
    ],
)
def test_bad_evaluate_input_exits_2(args, message, tmp_path, capsys):
    assert_exit_2(evaluate_main, [*args, "--json", str(tmp_path / "e.json")], message, capsys)
    assert not (tmp_path / "e.json").exists()


@pytest.mark.slow  # train.py runs in subprocesses
def test_sac_option_trains_checkpoints_its_replay_buffer_and_resumes(tmp_path):
    out = tmp_path / "sac"
    args = ["--algo", "sac", "--action-mode", "actuators", "--n-envs", "2", "--hp", "learning_starts=64",
            "--hp", "batch_size=32", "--eval-episodes", "1", "--checkpoint-freq", "128", "--no-progress-bar"]
    r = run("train.py", "--timesteps", "256", *args, "--out", out)
    assert r.returncode == 0, r.stderr[-3000:]
    ck = sorted((out / "checkpoints").glob("step_*"))[-1]
    assert (ck / "replay_buffer.npz").stat().st_size > 0
    r = run("train.py", "--timesteps", "384", *args, "--out", out, "--resume")
    assert r.returncode == 0, r.stderr[-3000:]
    newest = out / "checkpoints" / (out / "checkpoints" / "latest").read_text()
    assert json.loads((newest / "replay_buffer.json").read_text())["pos"] == 384 // 2
    # the extended run is bit for bit an uninterrupted 384-step run (the replay buffer was restored)
    r = run("train.py", "--timesteps", "384", *args, "--out", tmp_path / "ref")
    assert r.returncode == 0, r.stderr[-3000:]
    from safetensors.torch import load_file

    a, b = load_file(tmp_path / "ref" / "model.safetensors"), load_file(out / "model.safetensors")
    assert sorted(a) == sorted(b) and any(k.startswith("variables/log_ent_coef") for k in a)
    assert [k for k in a if not (a[k] == b[k]).all()] == []


def test_initial_weights_do_not_depend_on_the_machines_thread_count(tmp_path):
    """prepare() builds the model with SOFTPVTOL_TORCH_THREADS (1) torch threads, whatever torch's default (the
    machine's cores): orthogonal initialisation gives other weights with other thread counts."""
    import torch

    from softpvtol_gym.baselines.training.loop import prepare

    before = torch.get_num_threads()
    weights = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            cfg = RunConfig(seed=1, n_envs=2, hyperparams=load_hyperparams("ppo", "residual"))
            model = prepare(cfg, tmp_path / f"run{threads}")[2]
            assert torch.get_num_threads() == 1
            weights.append(torch.cat([p.detach().flatten() for p in model.policy.parameters()]))
    finally:
        torch.set_num_threads(before)
    assert torch.equal(weights[0], weights[1])


def test_run_config_records_the_base_loop_and_reads_legacy_configs_as_exact(tmp_path):
    """A run records the residual base loop it trains on (resolved: the env's default "bounded"); a
    config saved before the field existed is read as "exact", the env's default when it was trained."""
    import yaml

    from softpvtol_gym.baselines.config.hyperparams import LEGACY_CONTROLLER_LOOP
    from softpvtol_gym.baselines.config.run_config import RunConfig
    from softpvtol_gym.baselines.errors import ConfigError

    c = RunConfig(timesteps=1000)
    assert c.controller_loop == "bounded" and c.env_kwargs()["controller_loop"] == "bounded"
    assert RunConfig(timesteps=1000, controller_loop="paper").eval_env_kwargs() == {"controller_loop": "paper"}
    with pytest.raises(ConfigError, match="controller_loop"):
        RunConfig(controller_loop="convergent")
    with pytest.raises(ConfigError, match="controller_loop"):
        RunConfig(action_mode="actuators", controller_loop="ideal")
    path = tmp_path / "config.yaml"
    legacy = c.to_dict()
    del legacy["controller_loop"]
    path.write_text(yaml.safe_dump(legacy))
    assert RunConfig.load(path).controller_loop == LEGACY_CONTROLLER_LOOP == "exact"
    c.save(path)
    assert RunConfig.load(path).controller_loop == "bounded"
