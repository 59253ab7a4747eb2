"""Bad input to the commands (train.py, evaluate.py, run_jobs.py, leaderboard.py and the softpvtol
subcommands) and their failure modes.

* Bad arguments exit with code 2 and ONE line on stderr (no traceback) naming the problem, and write nothing.
  Each case is (script, argv, expected fragment of the message, setup). ``setup(tmp)`` prepares files in the
  case's own folder and returns a mapping for the argv placeholders ({tmp}, {run}, {spec}, ...). The folder is
  snapshotted after the setup: nothing in it may change (lock files aside). The evaluation and the training are
  replaced by functions that fail loudly, so that a case which gets that far fails.
* The commands check their outputs before any work, turn an OSError (disk full, read-only, permission) into one
  line naming the path (exit 74), report a killed worker without stopping the other jobs, refuse a malformed or
  non-finite leaderboard input without writing anything, and end on Ctrl-C / SIGTERM with exit 130 / 143, one
  line saying what was kept, and no worker process left behind.

The tests run as root in CI containers, where ``chmod`` stops nothing: unwritable outputs are paths under /proc
and /sys, a file used as a directory, and ``os`` functions patched to raise the OSError a full disk or a
read-only mount raises.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.leaderboard.jobs import EVAL_FILE, load_jobs, run_jobs
from softpvtol_gym.baselines.leaderboard.process_executor import ProcessPerJobExecutor, WorkerCrashed
from softpvtol_gym.baselines.util import args as args_mod
from softpvtol_gym.baselines.util.args import EXIT_IO_ERROR, EXIT_SIGINT, EXIT_SIGTERM, command_main
from softpvtol_gym.baselines.util.atomic import atomic_write_all
from tests.baselines._stub_jobs import StubJob, stub_entry
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
    import subprocess
    import sys

    from tests.conftest import ROOT

    r = subprocess.run([sys.executable, str(ROOT / "baselines" / "evaluate.py"), "--policy", "passivity", "--episodes",
                        "1000000000"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                       env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "at most 10,000" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []
    shutil.rmtree(tmp_path, ignore_errors=True)


REPO = Path(__file__).resolve().parents[2]
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
    line = _one_error_line(capsys.readouterr().err)
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
    line = _one_error_line(capsys.readouterr().err)
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

    data = json.loads((REPO / "results/leaderboard.json").read_text())
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


def _catches(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler installed for ``sig`` (its SigCgt mask)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (sig - 1)))
    return False


def _handles_sigterm(pid: int) -> bool:
    return _catches(pid, signal.SIGTERM)


def _as_from_a_terminal() -> None:
    """Run in a child before it starts: Ctrl-C at its default disposition, as in a shell. An ignored SIGINT is
    inherited, and Python then installs no KeyboardInterrupt handler; the worker processes of a parallel test run
    may ignore it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


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
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_as_from_a_terminal)
    try:
        deadline = time.monotonic() + 120
        while len(list(root.glob("*.pid"))) < 2:  # both workers are running their job
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        workers = [int(p.read_text()) for p in root.glob("*.pid")]
        assert _catches(proc.pid, sig), f"the driver has no handler for {signal.Signals(sig).name}"
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
                             "10000", "--json", str(out)], env=ENV, cwd=tmp_path,
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
def _ray_processes() -> list[str]:
    """Ray processes (raylet, GCS, workers) running on this machine now."""
    procs = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if any(k in cmd for k in ("raylet", "gcs_server", "default_worker.py", "ray::")):
                procs.append(f"{d.name}: {cmd[:80]}")
    return procs


def _ray_leftovers(temp_dir: Path) -> list[str]:
    """Ray processes and the folders the command left in its temporary directory (Ray's session folders, a
    search's storage): the command runs with TMPDIR=temp_dir, so another test's folders are not counted."""
    return _ray_processes() + [str(p) for pattern in ("ray-*", "softpvtol-tune-*") for p in temp_dir.glob(pattern)]


@pytest.fixture
def command_temp_dir():
    """A short, empty TMPDIR for a command that starts Ray (its Unix sockets need a short path)."""
    path = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def _signal_command(argv: list[str], cwd: Path, ready: str, sig: int, delay: float,
                    temp_dir: Path) -> tuple[int, str]:
    """Run ``softpvtol argv`` in ``cwd`` with TMPDIR=temp_dir; once it handles SIGTERM (the command has started)
    and its stdout shows ``ready``, wait ``delay`` s more and send ``sig``."""
    out = cwd / "stdout.txt"
    with open(out, "w") as fh:
        proc = subprocess.Popen([sys.executable, "-m", "softpvtol_gym.baselines", *argv],
                                env={**ENV, "TMPDIR": str(temp_dir)}, cwd=cwd,
                                stdout=fh, stderr=subprocess.PIPE, text=True, preexec_fn=_as_from_a_terminal)
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
    _wait_for_ray_to_exit()
    assert not _children(proc.pid)
    return proc.returncode, err


#: how long Ray's processes may take to exit after the command that stopped them (they exit asynchronously after
#: ``ray.shutdown``: 2-10 s measured on the 2-core machine, longer while another job loads it)
RAY_EXIT_SECONDS = 30.0


def _wait_for_ray_to_exit() -> None:
    deadline = time.monotonic() + RAY_EXIT_SECONDS
    while _ray_processes() and time.monotonic() < deadline:
        time.sleep(0.2)


@pytest.mark.slow  # a local Ray instance, twice: ~40 s
@pytest.mark.xdist_group("ray")
@pytest.mark.parametrize("when", ["starting", "running"])
def test_run_jobs_on_ray_terminated_leaves_no_ray_process_or_temp_folder(when, tmp_path, command_temp_dir):
    pytest.importorskip("ray")
    if _ray_processes():
        pytest.skip(f"another Ray is running here: {_ray_processes()[:2]}")
    # 4 jobs of 10,000 episodes: still running 8 s after Ray's start on a fast machine (one job of 5,000 took 5 s
    # on an AMX Xeon, and the SIGTERM then reached a process that had finished); SIGTERM ends them long before
    spec = _write_spec(tmp_path, episodes=10000, passivity=4)
    ready = "Ray:" if when == "running" else ""
    code, err = _signal_command(["run-jobs", "--executor", "ray", "--workers", "1", "--spec", str(spec), "--root",
                                 "runs"], tmp_path, ready, signal.SIGTERM, 8.0 if when == "running" else 4.0,
                                command_temp_dir)
    assert code == EXIT_SIGTERM, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("softpvtol run-jobs: error: terminated (SIGTERM): "), err
    assert "rerun: softpvtol run-jobs --executor ray" in line, line
    assert "Traceback" not in err and not _ray_leftovers(command_temp_dir)
    assert not (tmp_path / "runs" / ".run_jobs.token").exists()


@pytest.mark.slow  # a local Ray Tune search, interrupted: ~30 s
@pytest.mark.xdist_group("ray")
def test_tune_interrupted_writes_no_best_configuration(tmp_path, command_temp_dir):
    pytest.importorskip("ray")
    if _ray_processes():
        pytest.skip(f"another Ray is running here: {_ray_processes()[:2]}")
    space = tmp_path / "space.yml"
    space.write_text("ppo:\n  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n  n_epochs: {randint: [1, 2]}\n")
    code, err = _signal_command(["tune", "--trials", "4", "--workers", "1", "--space", str(space), "--out", "best.yml",
                                 "--hp", "n_envs=4", "--hp", "n_steps=32", "--hp", "batch_size=64", "--timesteps",
                                 "100000", "--reports", "4", "--eval-episodes", "2"], tmp_path, "Ray Tune:",
                                signal.SIGINT, 10.0, command_temp_dir)
    assert code == EXIT_SIGINT, err
    line = err.strip().splitlines()[-1]
    assert "interrupted (Ctrl-C): the search was stopped before its end, so no best configuration was written" in line
    assert "restore" not in err.lower() and "Traceback" not in err
    assert not (tmp_path / "best.yml").exists() and not _ray_leftovers(command_temp_dir)


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
