"""Atomic, resumable checkpoints of an SB3 run on the native vector env.

A checkpoint is a directory ``<run>/checkpoints/step_<NNNNNNNNNN>/`` holding

* ``model.zip``          the SB3 model (policy, optimizer, counters, last observation);
* ``vecnormalize.pkl``   the observation/reward normalisation statistics (``VecNormalize.save``);
* ``config.yaml``        the run's :class:`~baselines.config.RunConfig`;
* ``replay_buffer.pkl``   (off-policy algorithms only) the replay buffer;
* ``resume_state.pkl``   what an exact resume needs besides: the vector env's state (every sub-env
  mid-episode), VecNormalize's running discounted returns, and the numpy / torch / python RNG states.

It is written into a hidden temporary directory and renamed into place (atomic on one file system);
``checkpoints/latest`` (the step directory's name) is then replaced atomically. A process killed at
any moment leaves either the previous or the new checkpoint, never a half-written one.

Checkpoints are taken at rollout boundaries (after a PPO update, before the next rollout), so resuming
continues with exactly the steps that were not yet trained on: none lost, none repeated. For PPO on
this env the resumed run is bit for bit the uninterrupted one (tested).
"""

from __future__ import annotations

import os
import pickle
import random
import shutil
from pathlib import Path

import numpy as np
import torch

LATEST = "latest"
MODEL_FILE = "model.zip"
VECNORM_FILE = "vecnormalize.pkl"
CONFIG_FILE = "config.yaml"
STATE_FILE = "resume_state.pkl"
REPLAY_FILE = "replay_buffer.pkl"


def step_dir_name(step: int) -> str:
    return f"step_{step:010d}"


def save_checkpoint(run_dir: Path, model, vecnorm, config, keep: int = 2) -> Path:
    """Write a checkpoint of ``model`` (on ``vecnorm`` over the SB3 adapter) atomically; keep the
    newest ``keep`` checkpoints. Returns the checkpoint directory."""
    root = Path(run_dir) / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    name = step_dir_name(int(model.num_timesteps))
    final = root / name
    tmp = root / f".tmp_{name}_{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    model.save(tmp / MODEL_FILE)
    if vecnorm is not None:
        vecnorm.save(str(tmp / VECNORM_FILE))
    config.save(tmp / CONFIG_FILE)
    if getattr(model, "replay_buffer", None) is not None:  # off-policy algorithms (SAC)
        model.save_replay_buffer(tmp / REPLAY_FILE)
    state = {
        "num_timesteps": int(model.num_timesteps),
        "vector_env": _innermost(vecnorm if vecnorm is not None else model.get_env()).venv,
        "vecnormalize_returns": None if vecnorm is None else vecnorm.returns.copy(),
        "numpy_rng": np.random.get_state(),
        "torch_rng": torch.get_rng_state(),
        "python_rng": random.getstate(),
    }
    with open(tmp / STATE_FILE, "wb") as fh:
        pickle.dump(state, fh, protocol=pickle.HIGHEST_PROTOCOL)
    if final.exists():  # the same step again (a resumed run's first boundary): keep the old one
        shutil.rmtree(tmp)
    else:
        os.replace(tmp, final)
    _write_atomic(root / LATEST, name)
    for old in sorted(p for p in root.glob("step_*") if p.is_dir())[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint directory of a run, or None."""
    root = Path(run_dir) / "checkpoints"
    pointer = root / LATEST
    if pointer.is_file():
        cand = root / pointer.read_text().strip()
        if (cand / STATE_FILE).is_file():
            return cand
    done = sorted(p for p in root.glob("step_*") if (p / STATE_FILE).is_file())
    return done[-1] if done else None


def load_resume_state(checkpoint: Path) -> dict:
    with open(Path(checkpoint) / STATE_FILE, "rb") as fh:
        return pickle.load(fh)


def restore_rng(state: dict) -> None:
    np.random.set_state(state["numpy_rng"])
    torch.set_rng_state(state["torch_rng"])
    random.setstate(state["python_rng"])


def _innermost(venv):
    """The SoftPVTOLSB3VecEnv below any SB3 VecEnv wrappers."""
    from softpvtol_gym.envs.sb3 import SoftPVTOLSB3VecEnv

    while not isinstance(venv, SoftPVTOLSB3VecEnv):
        venv = venv.venv  # SB3 VecEnvWrapper
    return venv


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
