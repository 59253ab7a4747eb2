"""Bad input to the commands (train.py, evaluate.py, run_jobs.py, leaderboard.py and the softpvtol
subcommands), one case per row of a matrix: a bad argument exits with code 2 and ONE line on stderr (no
traceback) naming the problem, and writes nothing.

Each case is (script, argv, expected fragment of the message, setup). ``setup(tmp)`` prepares files in the case's
own folder and returns a mapping for the argv placeholders ({tmp}, {run}, {spec}, ...). The folder is snapshotted
after the setup: nothing in it may change (lock files aside). The evaluation and the training are replaced by
functions that fail loudly, so that a case which gets that far fails. Input/output failures are tested in
``test_io_errors.py``, interrupts in ``test_interrupts.py``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.baselines._commands import ENV, REPO
from tests.conftest import UP, copy_run, rewrite_manifest

SPEC = {
    "evaluation": {"episodes": 1, "seed": 1_000_000, "tiers": ["nominal"]},
    "passivity": [{"name": "passivity-exact", "allocation": "exact"}],
    "tasks": ["hover"],
    "trained": [],
    "seeds": [0],
}


# ------------------------------------------------------------------------------------ setups
def nothing(tmp: Path) -> dict:
    return {}


def a_file(tmp: Path) -> dict:
    (tmp / "notes.txt").write_text("not a checkpoint\n")
    return {}


def run_copy(tmp: Path) -> Path:
    return copy_run(_TINY["request"].getfixturevalue("tiny_run"), tmp / "run")


def a_run(tmp: Path) -> dict:
    run_copy(tmp)
    return {}


def tamper(name: str, content, forge: bool = True, folder: str = ""):
    """A copy of the tiny run with ``name`` (in the run folder, or ``folder`` under it) replaced by
    ``content`` (bytes, str, or a function of the old text; None deletes it); the manifest rewritten to
    match (``forge``), so that the loader's own checks, not the checksum, must catch the problem."""

    def setup(tmp: Path) -> dict:
        run = run_copy(tmp)
        target = run / folder / name
        if content is None:
            target.unlink()
        elif callable(content):
            target.write_text(content(target.read_text()))
        else:
            target.write_bytes(content if isinstance(content, bytes) else content.encode())
        if forge and name != "checkpoint.json":
            rewrite_manifest(run / folder)
        return {}

    return setup


def sac_config_on_ppo_weights(tmp: Path) -> dict:
    """A consistent SAC config and manifest over the weights of a PPO model (a SAC/PPO mix-up)."""
    run = run_copy(tmp)
    import yaml

    cfg = yaml.safe_load((run / "config.yaml").read_text())
    cfg["algo"] = "sac"
    cfg["hyperparams"] = {k: v for k, v in cfg["hyperparams"].items() if k in ("policy", "n_envs", "normalize")}
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    manifest = json.loads((run / "checkpoint.json").read_text())
    manifest["algo"] = "sac"
    (run / "checkpoint.json").write_text(json.dumps(manifest))
    rewrite_manifest(run)
    return {}


def config_edit(**changes):
    def edit(text: str) -> str:
        import yaml

        data = yaml.safe_load(text)
        for k, v in changes.items():
            if v is _DELETE:
                del data[k]
            elif isinstance(v, dict) and isinstance(data.get(k), dict):
                data[k] = {**data[k], **v}
            else:
                data[k] = v
        return yaml.safe_dump(data, sort_keys=False)

    return edit


_DELETE = object()


def json_edit(fn):
    def edit(text: str) -> str:
        data = json.loads(text)
        fn(data)
        return json.dumps(data)

    return edit


def spec(text_or_changes=None, **changes):
    """A spec file: the YAML text given, or SPEC with top-level ``changes`` (None deletes a key)."""

    def setup(tmp: Path) -> dict:
        path = tmp / "spec.yml"
        if isinstance(text_or_changes, str):
            path.write_text(text_or_changes)
        else:
            import yaml

            data = json.loads(json.dumps(SPEC))
            for k, v in changes.items():
                if v is None:
                    data.pop(k, None)
                elif isinstance(v, dict) and k == "evaluation":
                    data[k] = {**data[k], **v}
                    data[k] = {kk: vv for kk, vv in data[k].items() if vv is not None}
                else:
                    data[k] = v
            path.write_text(yaml.safe_dump(data))
        return {}

    return setup


def spec_and_results(eval_content):
    def setup(tmp: Path) -> dict:
        spec()(tmp)
        job = tmp / "root" / "passivity-exact_hover"
        job.mkdir(parents=True)
        (job / "eval.json").write_text(eval_content)
        return {}

    return setup


def leaderboard_json(content):
    def setup(tmp: Path) -> dict:
        path = tmp / "lb.json"
        if callable(content):
            from tests.conftest import LEADERBOARD_JSON

            data = json.loads(LEADERBOARD_JSON.read_text())
            content(data)
            path.write_text(json.dumps(data))
        else:
            path.write_text(content)
        return {}

    return setup


def locked(subdir: str, then=nothing):
    """``then``'s setup, and the folder ``subdir`` locked by another process."""

    def setup(tmp: Path) -> dict:
        out = then(tmp)
        _TINY["hold"](tmp / subdir)
        return out

    return setup


# ------------------------------------------------------------------------------------- cases
T, E, R, L = "train.py", "evaluate.py", "run_jobs.py", "leaderboard.py"
SHORT = ["--timesteps", "64", "--n-envs", "2", "--hp", "n_steps=32", "--hp", "batch_size=32", "--no-progress-bar",
         "--out", "{tmp}/out"]


def short_with(item: str) -> list[str]:
    """SHORT with one more ``--hp`` override; it replaces SHORT's own for the same key (a key given twice is an
    error of its own)."""
    key = item.partition("=")[0]
    out = list(SHORT)
    for i in range(len(out) - 1):
        if out[i] == "--hp" and out[i + 1].partition("=")[0] == key:
            del out[i:i + 2]
            break
    return [*out, "--hp", item]


CASES = [
    # ----------------------------------------------------------------------------- train.py
    (T, ["--algo", "dqn", *SHORT], "invalid choice", nothing),
    (T, ["--action-mode", "joystick", *SHORT], "invalid choice", nothing),
    (T, ["--task", "loop", *SHORT], "invalid choice", nothing),
    (T, ["--tier", "extreme", *SHORT], "invalid choice", nothing),
    (T, [*SHORT, "--timesteps", "-5"], "--timesteps must be >= 1", nothing),
    (T, [*SHORT, "--timesteps", "0"], "--timesteps must be >= 1", nothing),
    (T, [*SHORT, "--timesteps", "abc"], "expected an integer", nothing),
    (T, [*SHORT, "--timesteps", "1e6"], "expected an integer", nothing),
    (T, [*SHORT, "--timesteps", str(10**11)], "timesteps must be an integer in", nothing),
    (T, [*SHORT, "--seed", "-1"], "--seed must be in", nothing),
    (T, [*SHORT, "--seed", "500000"], "--seed must be in", nothing),
    (T, [*SHORT, "--seed", "x"], "expected an integer", nothing),
    (T, [*SHORT, "--n-envs", "0"], "--n-envs must be >= 1", nothing),
    (T, [*SHORT, "--n-envs", "100000"], "n_envs must be an integer", nothing),
    (T, [*SHORT, "--checkpoint-freq", "0"], "--checkpoint-freq must be >= 1", nothing),
    (T, [*SHORT, "--eval-freq", "0"], "--eval-freq must be >= 1", nothing),
    (T, [*SHORT, "--eval-episodes", "-1"], "--eval-episodes must be >= 0", nothing),
    (T, [*SHORT, "--eval-episodes", "100000"], "eval_episodes must be an integer in", nothing),
    (T, short_with("n_epochs"), "key=value", nothing),
    (T, short_with("=5"), "key=value", nothing),
    (T, short_with("foo=1"), "unknown hyperparameter 'foo' for PPO", nothing),
    (T, short_with("n_steps=0"), "n_steps must be an integer >= 1", nothing),
    (T, short_with("batch_size=0"), "batch_size must be an integer >= 2", nothing),
    (T, short_with("batch_size=1"), "batch_size must be an integer >= 2", nothing),
    (T, short_with("learning_rate=-1"), "learning_rate must be a finite number > 0", nothing),
    (T, short_with("learning_rate=0"), "learning_rate must be a finite number > 0", nothing),
    (T, short_with("learning_rate=inf"), "learning_rate must be a finite number", nothing),
    (T, short_with("learning_rate=abc"), "learning_rate must be a finite number", nothing),
    (T, short_with("learning_rate=[1, 2]"), "learning_rate must be a finite number", nothing),
    (T, short_with("gamma=nan"), "gamma must be a finite number > 0 and <= 1", nothing),
    (T, short_with("gamma=0"), "gamma must be a finite number > 0 and <= 1", nothing),
    (T, short_with("gamma=1.5"), "gamma must be a finite number > 0 and <= 1", nothing),
    (T, short_with("gamma=true"), "gamma must be a finite number", nothing),
    (T, short_with("gae_lambda=2"), "gae_lambda must be", nothing),
    (T, short_with("clip_range=-0.1"), "clip_range must be a finite number > 0", nothing),
    (T, short_with("clip_range_vf=0"), "clip_range_vf must be null or", nothing),
    (T, short_with("n_epochs=0"), "n_epochs must be an integer >= 1", nothing),
    (T, short_with("n_epochs=2.5"), "n_epochs must be an integer", nothing),
    (T, short_with("ent_coef=-1"), "ent_coef must be a finite number >= 0", nothing),
    (T, short_with("max_grad_norm=0"), "max_grad_norm must be a finite number > 0", nothing),
    (T, short_with("target_kl=-1"), "target_kl must be null or", nothing),
    (T, short_with("normalize=5"), "normalize must be true, false, or a mapping", nothing),
    (T, short_with("normalize={{foo: 1}}"), "unknown: ['foo']", nothing),
    (T, short_with("normalize={{gamma: 2}}"), "whose gamma is", nothing),
    (T, short_with("normalize={{norm_obs: maybe}}"), "whose norm_obs is true or false", nothing),
    (T, short_with("policy=CnnPolicy"), "policy must be 'MlpPolicy'", nothing),
    (T, short_with("policy_kwargs=dict(activation_fn=__import__('os'))"), "only hold", nothing),
    (T, short_with("policy_kwargs=dict(net_arch=[8], bogus=1)"), "stable-baselines3 refused", nothing),
    (T, short_with("policy_kwargs=dict("), "policy_kwargs must be a dict(...) expression", nothing),
    (T, short_with("policy_kwargs=5"), "policy_kwargs must be a dict", nothing),
    (T, short_with("rollout_buffer_class=DictRolloutBuffer"), "rollout_buffer_class must be null", nothing),
    (T, [*short_with("n_steps=1"), "--n-envs", "1"], "n_steps * n_envs must be > 1", nothing),
    (T, short_with("n_steps=100000000"), "n_steps * n_envs must be <=", nothing),
    (T, short_with("n_steps=[1"), "is not valid YAML", nothing),
    (T, ["--timesteps", "64", "--hp", "n_envs=0", "--out", "{tmp}/out"], "n_envs must be an integer in", nothing),
    (T, short_with("n_timesteps=0"), "n_timesteps must be an integer >= 1", nothing),
    (T, short_with("seed=3"), "unknown hyperparameter 'seed'", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "n_epochs=5"], "unknown hyperparameter 'n_epochs' for SAC", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "tau=2"], "tau must be a finite number > 0 and <= 1", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "buffer_size=0"], "buffer_size must be an integer >= 1", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "buffer_size=100000000000"], "buffer_size must be an integer", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "ent_coef=auto_x"], "ent_coef must be 'auto'", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "ent_coef=0"], "ent_coef must be 'auto'", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "train_freq=0"], "train_freq must be an integer >= 1 or", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "train_freq=[4, hour]"], "train_freq must be", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "gradient_steps=0"], "gradient_steps must be", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "learning_starts=-1"], "learning_starts must be an integer >= 0", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "action_noise=normal"], "action_noise must be null", nothing),
    (T, ["--algo", "sac", *SHORT, "--hp", "target_entropy=low"], "target_entropy must be 'auto'", nothing),
    (T, [*SHORT, "--train-env", "precision_reward_weight=1", "--train-env", "precision_reward_weight=2"],
     "--train-env precision_reward_weight is given twice", nothing),
    (T, [*SHORT, "--env", "residual_scale=0.4", "--env", "residual_scale=0.4"], "--env residual_scale is given twice",
     nothing),
    (T, ["--resume", *SHORT], "does not exist", nothing),
    (T, ["--timesteps", "64", "--out", "{tmp}/notes.txt"], "is a file", a_file),
    (T, [*SHORT[:-2], "--out", "{tmp}/run"], "already holds a run", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--task", "track_paper"], "--resume: task of", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--hp", "n_epochs=3"], "--resume: hyperparams of", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--n-envs", "8"], "--resume: n_envs of", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--algo", "sac"], "--resume: algo of", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--recipe", "residual-precise"], "records no recipe", a_run),
    (T, ["--out", "{tmp}/run", "--resume", "--recipe", "residual-precise"],
     "is 'residual-integral', the command asks for 'residual-precise'; resume with the run's own recipe",
     tamper("config.yaml", config_edit(recipe="residual-integral"))),
    (T, [*SHORT[:-2], "--out", "{tmp}/out"], "is in use by pid", locked("out")),
    (T, ["--bogus"], "unrecognized arguments", nothing),
    (T, SHORT, "SOFTPVTOL_TORCH_THREADS must be an integer", lambda tmp: {"env": {"SOFTPVTOL_TORCH_THREADS": "many"}}),
    # ---------------------------------------------------------------------------- evaluate.py
    (E, ["--policy", "{tmp}/no/such/checkpoint"], "does not exist", nothing),
    (E, ["--policy", "passivity", "--action-mode", "joystick"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--task", "loop"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--tier", "extreme"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--allocation", "magic"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--controller-loop", "convergent"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--controller-loop", "ideal"], "invalid choice", nothing),
    (E, ["--policy", "passivity", "--controller-loop", "paper", "--allocation", "exact"], "uses the paper allocation",
     nothing),
    (E, ["--policy", "passivity", "--action-mode", "virtual", "--controller-loop", "extended"],
     "--controller-loop extended is a policy acting on the actuators only, got --action-mode virtual", nothing),
    (E, ["--policy", "passivity", "--action-mode", "residual", "--controller-loop", "extended"],
     "pass --action-mode actuators", nothing),
    (E, ["--policy", "{tmp}/run", "--controller-loop", "extended"],
     "cannot be the base controller of a residual checkpoint", a_run),
    (E, ["--policy", "passivity", "--episodes", "0"], "--episodes must be >= 1", nothing),
    (E, ["--policy", "passivity", "--episodes", "-3"], "--episodes must be >= 1", nothing),
    (E, ["--policy", "passivity", "--episodes", "1e9"], "expected an integer", nothing),
    (E, ["--policy", "passivity", "--episodes", "1000000000"], "at most 10,000", nothing),
    (E, ["--policy", "passivity", "--episodes", "many"], "expected an integer", nothing),
    (E, ["--policy", "passivity", "--seed", "-1"], "--seed must be >= 0", nothing),
    (E, ["--policy", "passivity", "--seed", "abc"], "expected an integer", nothing),
    (E, ["--policy", "passivity", "--seed", str(2**63)], "--seed must be >= 0", nothing),
    (E, ["--policy", "passivity", "--json", "{tmp}"], "is a directory", nothing),
    (E, ["--policy", "passivity", "--json", "{tmp}/notes.txt"], "exists; pass --force", a_file),
    (E, ["--policy", "passivity", "--json", "{tmp}/notes.txt/out.json"], "is a file, not a directory", a_file),
    (E, ["--episodes", "1"], "the following arguments are required: --policy", nothing),
    (E, ["--policy", "passivity", "--bogus"], "unrecognized arguments", nothing),
    (E, ["--policy", "{tmp}/notes.txt"], "is not a checkpoint (a 17-byte file)", a_file),
    (E, ["--policy", "{tmp}"], "holds no checkpoint", nothing),
    (E, ["--policy", "{tmp}/run/model.zip"], "pickle-based file", tamper("model.zip", b"PK", forge=False)),
    (E, ["--policy", "{tmp}/run/vecnormalize.pkl"], "pickle-based file",
     tamper("vecnormalize.pkl", b"\x80\x04", forge=False)),
    (E, ["--policy", "{tmp}/legacy"], "holds only pickle-based files", lambda tmp: (
        (tmp / "legacy").mkdir(), (tmp / "legacy" / "model.zip").write_bytes(b"PK"), {})[-1]),
    (E, ["--policy", "{tmp}/run", "--action-mode", "actuators"], "does not match the checkpoint's action mode", a_run),
    (E, ["--policy", "{tmp}/run"], "run config", tamper("config.yaml", "")),
    (E, ["--policy", "{tmp}/run"], "is not valid YAML", tamper("config.yaml", "algo: [ppo\n")),
    (E, ["--policy", "{tmp}/run"], "is a list", tamper("config.yaml", "- ppo\n")),
    (E, ["--policy", "{tmp}/run"], "unknown keys ['colour']", tamper("config.yaml", config_edit(colour="red"))),
    (E, ["--policy", "{tmp}/run"], "lacks the keys ['seed']", tamper("config.yaml", config_edit(seed=_DELETE))),
    (E, ["--policy", "{tmp}/run"], "says PPO, config.yaml says SAC", tamper("config.yaml", config_edit(algo="sac"))),
    (E, ["--policy", "{tmp}/run"], "weights are of a PPO model, config.yaml says SAC", sac_config_on_ppo_weights),
    (E, ["--policy", "{tmp}/run"], "gamma must be", tamper("config.yaml", config_edit(hyperparams={"gamma": 7}))),
    (E, ["--policy", "{tmp}/run"], "task must be one of", tamper("config.yaml", config_edit(task="loop"))),
    (E, ["--policy", "{tmp}/run"], "do not fit the network",
     tamper("config.yaml", config_edit(hyperparams={"policy_kwargs": "dict(net_arch=[8])"}))),
    (E, ["--policy", "{tmp}/run"], "has no vecnormalize.json", tamper("vecnormalize.json", None)),
    (E, ["--policy", "{tmp}/run"], "is present but config.yaml has no normalisation",
     tamper("config.yaml", config_edit(hyperparams={"normalize": False}))),
    (E, ["--policy", "{tmp}/run"], "obs_rms has shape",
     tamper("vecnormalize.json", json_edit(lambda d: d["obs_rms"].update(mean=[0.0]))),),
    (E, ["--policy", "{tmp}/run"], "non-finite",
     tamper("vecnormalize.json", json_edit(lambda d: d["obs_rms"]["mean"].__setitem__(0, float("nan"))))),
    (E, ["--policy", "{tmp}/run"], "is not a readable safetensors file", tamper("model.safetensors", b"\x00" * 10)),
    (E, ["--policy", "{tmp}/run"], "corrupt or was changed", tamper("model.safetensors", b"\x00" * 10, forge=False)),
    (E, ["--policy", "{tmp}/run"], "model.json is not valid JSON", tamper("model.json", "{")),
    (E, ["--policy", "{tmp}/run"], "is not a version-1 model description",
     tamper("model.json", json_edit(lambda d: d.update(version=99)))),
    (E, ["--policy", "{tmp}/run"], "checkpoint.json is not readable JSON", tamper("checkpoint.json", "{")),
    (E, ["--policy", "{tmp}/run"], "is not a softpvtol-gym checkpoint manifest",
     tamper("checkpoint.json", json_edit(lambda d: d.update(format="other")))),
    (E, ["--policy", "{tmp}/run"], "format version 2",
     tamper("checkpoint.json", json_edit(lambda d: d.update(version=2)))),
    (E, ["--policy", "{tmp}/run"], f"invalid file entry '{UP}/config.yaml'",
     tamper("checkpoint.json", json_edit(lambda d: d["files"].update({f"{UP}/config.yaml": {}})))),
    (E, ["--policy", "{tmp}/run"], "is incomplete: gone.bin is missing",
     tamper("checkpoint.json", json_edit(lambda d: d["files"].update({"gone.bin": {}})))),
    (E, ["--policy", "{tmp}/run"], "says 999 steps",
     tamper("checkpoint.json", json_edit(lambda d: d.update(num_timesteps=999)))),
    (E, ["--policy", "{tmp}/run"], "is not a readable safetensors file",
     tamper("model.safetensors", b"\x80\x04K\x01.")),
    # ----------------------------------------------------------------------------- run_jobs.py
    (R, ["--workers", "0", "--spec", "{tmp}/spec.yml"], "--workers must be in [1, 256]", spec()),
    (R, ["--workers", "-1", "--spec", "{tmp}/spec.yml"], "--workers must be in", spec()),
    (R, ["--workers", "abc"], "expected an integer", nothing),
    (R, ["--workers", "1000"], "--workers must be in", spec()),
    (R, ["--spec", "{tmp}/missing.yml"], "no leaderboard spec at", nothing),
    (R, ["--only", "", "--spec", "{tmp}/spec.yml"], "--only '' would match every job", spec()),
    (R, ["--only", " ", "--spec", "{tmp}/spec.yml"], "--only ' ' would match every job", spec()),
    (R, ["--spec", "{tmp}/spec.yml"], "more than the 1,048,576 a YAML file may have",
     spec("evaluation: {}\n# " + "x" * 2**20 + "\n")),
    (R, ["--spec", "{tmp}"], "(it is a directory)", nothing),
    (R, ["--spec", "{tmp}/spec.yml"], "is not valid YAML at line", spec("evaluation: [1\n")),
    (R, ["--spec", "{tmp}/spec.yml"], "is empty", spec("")),
    (R, ["--spec", "{tmp}/spec.yml"], "must be a mapping", spec("- 1\n- 2\n")),
    (R, ["--spec", "{tmp}/spec.yml"], "lacks the keys ['evaluation']", spec(evaluation=None)),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation lacks the keys ['tiers']", spec(evaluation={"tiers": None})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.episodes must be an integer", spec(evaluation={"episodes": 0})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.episodes must be an integer", spec(evaluation={"episodes": "a"})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.episodes must be an integer in [1, 10,000]",
     spec(evaluation={"episodes": 10**9})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.episodes must be", spec(evaluation={"episodes": True})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.seed must be an integer >= 1,000,000", spec(evaluation={"seed": 5})),
    (R, ["--spec", "{tmp}/spec.yml"], "each of evaluation.tiers must be one of",
     spec(evaluation={"tiers": ["extreme"]})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation.tiers must be a non-empty list", spec(evaluation={"tiers": []})),
    (R, ["--spec", "{tmp}/spec.yml"], "lists a tier twice", spec(evaluation={"tiers": ["wind", "wind"]})),
    (R, ["--spec", "{tmp}/spec.yml"], "evaluation has unknown keys ['repeats']", spec(evaluation={"repeats": 2})),
    (R, ["--spec", "{tmp}/spec.yml"], "has unknown keys ['colour']", spec(colour="red")),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds must be integers", spec(seeds=["a"])),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds must be integers", spec(seeds=[-1])),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds must be integers", spec(seeds=[True])),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds lists a seed twice", spec(seeds=[1, 1])),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds must be a list", spec(seeds=5)),
    (R, ["--spec", "{tmp}/spec.yml"], "each of tasks must be one of", spec(tasks=["loop"])),
    (R, ["--spec", "{tmp}/spec.yml"], "tasks must be a non-empty list", spec(tasks=[])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0].name must be a lower-case name",
     spec(passivity=[{"name": f"{UP}/{UP}/{UP}/{UP}/x", "allocation": "exact"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0].name must be",
     spec(passivity=[{"name": "/abs", "allocation": "exact"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0].name must be",
     spec(passivity=[{"name": "Upper", "allocation": "exact"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0] lacks the keys ['name']",
     spec(passivity=[{"allocation": "exact"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0].allocation must be one of",
     spec(passivity=[{"name": "p", "allocation": "magic"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity[0] has unknown keys ['gains']",
     spec(passivity=[{"name": "p", "allocation": "exact", "gains": 2}])),
    (R, ["--spec", "{tmp}/spec.yml"], "is taken", spec(passivity=[{"name": "p", "allocation": "exact"},
                                                                  {"name": "p", "allocation": "paper"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "passivity must be a list", spec(passivity={"name": "p"})),
    (R, ["--spec", "{tmp}/spec.yml"], "trained[0] has unknown keys ['lr']", spec(trained=[
        {"action_mode": "residual", "task": "hover", "tier": "nominal", "timesteps": 64, "lr": 1}])),
    (R, ["--spec", "{tmp}/spec.yml"], "trained[0].action_mode must be one of", spec(trained=[
        {"action_mode": "joystick", "task": "hover", "tier": "nominal", "timesteps": 64}])),
    (R, ["--spec", "{tmp}/spec.yml"], "trained[0].timesteps must be an integer", spec(trained=[
        {"action_mode": "residual", "task": "hover", "tier": "nominal", "timesteps": 0}])),
    (R, ["--spec", "{tmp}/spec.yml"], "trained[0].timesteps must be an integer", spec(trained=[
        {"action_mode": "residual", "task": "hover", "tier": "nominal", "timesteps": "many"}])),
    (R, ["--spec", "{tmp}/spec.yml"], "repeats the cell", spec(trained=[
        {"action_mode": "residual", "task": "hover", "tier": "nominal", "timesteps": 64}] * 2)),
    (R, ["--spec", "{tmp}/spec.yml"], "seeds must be a non-empty list", spec(trained=[
        {"action_mode": "residual", "task": "hover", "tier": "nominal", "timesteps": 64}], seeds=[])),
    (R, ["--spec", "{tmp}/spec.yml", "--root", "{tmp}/notes.txt"], "is a file", lambda tmp: {**spec()(tmp),
                                                                                              **a_file(tmp)}),
    (R, ["--spec", "{tmp}/spec.yml", "--only", "nothing-like-this"], "matches no job", spec()),
    (R, ["--spec", "{tmp}/spec.yml", "--root", "{tmp}/root"], "job root", locked("root", spec())),
    (R, ["--spec", "{tmp}/spec.yml", "--bogus"], "unrecognized arguments", spec()),
    # --------------------------------------------------------------------------- leaderboard.py
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "meta is missing", leaderboard_json("{}")),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "is not valid JSON", leaderboard_json('{"meta": {"command": "x", "comm')),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "expected an object", leaderboard_json("[1, 2]")),
    (L, ["--from-json", "--json", "{tmp}/none.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "no leaderboard JSON at", nothing),
    (L, ["--from-json", "--json", "{tmp}", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "is a directory", nothing),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "meta.tiers must be a list", leaderboard_json(lambda d: d["meta"].pop("tiers"))),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "is not one of meta.tiers", leaderboard_json(lambda d: d["aggregates"][0].update(tier="extreme"))),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "must be a list of two finite numbers",
     leaderboard_json(lambda d: d["aggregates"][0].update(crash_rate_ci=[0.1]))),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "must be a finite number", leaderboard_json(lambda d: d["aggregates"][0].update(return_iqm="high"))),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png"],
     "is not valid JSON", leaderboard_json("\x00\x01binary")),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}", "--chart", "{tmp}/c.png"],
     "--markdown", leaderboard_json(lambda d: None)),
    (L, ["--from-json", "--json", "{tmp}/lb.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}"],
     "--chart", leaderboard_json(lambda d: None)),
    (L, ["--json", "{tmp}", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}/root"], "--json", spec()),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}"], "is not valid YAML", spec("tasks: [hover\n")),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}"], "has unknown keys ['extra']", spec(extra=1)),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}/missing"], "--root", spec()),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}"], "no results under", spec()),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}/root"], "eval.json is not readable JSON", spec_and_results('{"job": ')),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}/root"], "is not a job result", spec_and_results("[]")),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}/root"], "holds the result of another job", spec_and_results(json.dumps(
             {"job": {"policy": "passivity-paper", "task": "hover", "seed": 0}, "checkpoint": None,
              "train_seconds": None, "eval": {}}))),
    (L, ["--json", "{tmp}/o.json", "--markdown", "{tmp}/L.md", "--chart", "{tmp}/c.png", "--spec", "{tmp}/spec.yml",
         "--root", "{tmp}"], "passivity[0].name must be",
     spec(passivity=[{"name": f"{UP}/{UP}/x", "allocation": "exact"}])),
    (L, ["--bogus"], "unrecognized arguments", nothing),
]

_TINY: dict = {}


@pytest.fixture(autouse=True)
def _shared(request, lock_holder):
    # the tiny run is trained (or waited for, under xdist) only by the cases that copy it
    _TINY["request"], _TINY["hold"] = request, lock_holder
    yield


def _main(script: str):
    if script == T:
        from softpvtol_gym.baselines.commands.train import main
    elif script == E:
        from softpvtol_gym.baselines.commands.evaluate import main
    elif script == R:
        from softpvtol_gym.baselines.commands.run_jobs import main
    else:
        from softpvtol_gym.baselines.commands.leaderboard import main
    return main


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*")) if ".softpvtol.lock" not in p.name}


def _ids():
    seen: dict = {}
    for script, _argv, message, _ in CASES:
        base = f"{script.split('.')[0]}-{message[:40]}"
        seen[base] = seen.get(base, 0) + 1
        yield base if seen[base] == 1 else f"{base}-{seen[base]}"


def test_the_matrix_has_enough_cases():
    assert len(CASES) >= 80, len(CASES)


@pytest.mark.parametrize("script, argv, message, setup", CASES, ids=list(_ids()))
def test_bad_script_input_exits_2_with_one_line_and_writes_nothing(script, argv, message, setup, tmp_path, capsys,
                                                                   monkeypatch):
    import softpvtol_gym.baselines.commands.evaluate as evaluate_command
    import softpvtol_gym.baselines.commands.train as train_command
    import softpvtol_gym.baselines.evaluation as evaluation

    def refuse(*args, **kwargs):
        raise AssertionError("reached the evaluation / training: the bad input was not caught before it")

    # the case's files first: a setup may train the shared tiny run, which must not meet the refusals below
    case = tmp_path / "case"
    case.mkdir()
    names = {"tmp": str(case), **(setup(case) or {})}
    monkeypatch.setattr(evaluate_command, "evaluate", refuse)
    monkeypatch.setattr(evaluation, "evaluate", refuse)
    if script == T and "already holds" not in message and "--resume:" not in message and "in use" not in message:
        monkeypatch.setattr(train_command, "train", refuse)
    for key, value in names.pop("env", {}).items():
        monkeypatch.setenv(key, value)
    before = _snapshot(tmp_path)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        _main(script)([a.format(**names) for a in argv])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert exc.value.code == 2, (exc.value.code, err[-2000:])
    assert len(lines) == 1 and "Traceback" not in err, err[-2000:]
    assert lines[0].startswith(f"{script}: error: ") and message in lines[0], lines[0]
    assert _snapshot(tmp_path) == before, "files were written or changed"


def test_a_bad_input_in_a_real_process_prints_one_line(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "baselines" / "evaluate.py"), "--policy", "passivity", "--episodes",
                        "1000000000"], cwd=tmp_path, capture_output=True, text=True, timeout=300, env=ENV)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "at most 10,000" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []
