"""SB3's pickle-based files (model.zip, vecnormalize.pkl): the only place that unpickles, reached only with
an explicit trust_pickle / --trust-pickle."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.checkpoints.load import load_folder
from softpvtol_gym.baselines.checkpoints.manifest import CONFIG_FILE
from softpvtol_gym.baselines.checkpoints.model_state import check_tensors, model_payload, vecnorm_dict
from softpvtol_gym.baselines.checkpoints.store import find_checkpoint, warn, write_model_files
from softpvtol_gym.baselines.config.hyperparams import normalize_kwargs
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError, ConfigError
from softpvtol_gym.baselines.training.models import algo_class, make_env
from softpvtol_gym.baselines.util.atomic import atomic_path, atomic_write_bytes

PICKLE_WARNING = ("unpickling {files}: this runs any code they contain; only do this for files you created or whose "
                  "source you trust (--trust-pickle)")


def legacy_paths(path: Path) -> tuple[Path, Path | None, Path]:
    """(model.zip, vecnormalize.pkl or None, config.yaml) of a pickle-based run folder or zip."""

    path = Path(path)
    if path.is_dir():
        zip_path = path / "model.zip"
    elif path.is_file() and path.suffix == ".zip":
        zip_path = path
    elif path.is_file() and path.name == "vecnormalize.pkl":
        zip_path = path.parent / "model.zip"
    else:
        raise CheckpointError(f"{path} is neither an SB3 model.zip nor a folder holding one")
    if not zip_path.is_file():
        raise CheckpointError(f"no SB3 model.zip at {zip_path}")
    folder = zip_path.parent
    pkl = folder / "vecnormalize.pkl"
    for cfg in (folder / CONFIG_FILE, folder.parent / CONFIG_FILE):
        if cfg.is_file():
            return zip_path, (pkl if pkl.is_file() else None), cfg
    raise CheckpointError(f"no config.yaml next to {zip_path} or one folder up: the run's settings are needed")


def _read_pickled(path: Path):
    """(model, VecNormalize or None, RunConfig) of pickle-based files, as saved, with a warning."""

    zip_path, pkl, cfg = legacy_paths(path)
    config = RunConfig.load(cfg)
    if normalize_kwargs(config.hyperparams) is not None and pkl is None:
        raise CheckpointError(f"{cfg} asks for normalisation but there is no vecnormalize.pkl next to {zip_path}")
    if pkl is not None and normalize_kwargs(config.hyperparams) is None:
        raise CheckpointError(f"{pkl} is present but {cfg} has no normalisation")
    warn(PICKLE_WARNING.format(files=", ".join(str(p) for p in (zip_path, pkl) if p is not None)))
    model = algo_class(config.algo).load(zip_path, device="cpu")
    vecnorm = None
    if pkl is not None:
        from stable_baselines3.common.vec_env import VecNormalize

        vecnorm = VecNormalize.load(str(pkl), make_env(config, 1))
    return model, vecnorm, config, zip_path, cfg


def load_pickled(path: Path):
    """``(model, VecNormalize or None, RunConfig)`` from pickle-based files (an SB3 zip and VecNormalize
    pickle), ready for evaluation, with a warning. Only reached with an explicit trust_pickle / --trust-pickle
    (:meth:`~softpvtol_gym.baselines.training.policy.LearnedPolicy.load` wraps it)."""
    model, vecnorm, config, _, _ = _read_pickled(path)
    if vecnorm is not None:
        vecnorm.training = False
        vecnorm.norm_reward = False
    return model, vecnorm, config


def from_sb3(path: Path, out: Path | None = None) -> Path:
    """Convert pickle-based files to the safe format (see the module docstring); returns the folder."""

    model, vecnorm, config, zip_path, cfg = _read_pickled(path)
    check_tensors(model_payload(model)[0], str(zip_path))  # no NaN / huge weights into the safe format
    if vecnorm is not None:
        stats = vecnorm_dict(vecnorm)
        for name in ("obs_rms", "ret_rms"):
            r = stats[name]
            if not (np.isfinite(r["mean"]).all() and np.isfinite(r["var"]).all() and np.isfinite(r["count"])):
                raise CheckpointError(f"{zip_path.parent / 'vecnormalize.pkl'}: {name} holds non-finite statistics")
    out = zip_path.parent if out is None else Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if cfg != out / CONFIG_FILE:  # the config next to the model (a checkpoint folder holds its own)
        config.save(out / CONFIG_FILE)
    write_model_files(out, model, vecnorm, config, "run")
    return out


def to_sb3(policy_path: Path, out: Path, vecnormalize: Path | None = None) -> None:
    """Write an SB3 zip (and the VecNormalize pickle) of a safe checkpoint."""

    model, vecnorm, _, _ = load_folder(find_checkpoint(policy_path))
    if vecnorm is not None and vecnormalize is None:
        raise ConfigError(f"{policy_path} has observation normalisation: pass --vecnormalize PATH for its statistics "
                          f"(SB3 needs them to use the model)")
    buf = io.BytesIO()
    model.save(buf)
    atomic_write_bytes(out, buf.getvalue())
    if vecnorm is not None:
        with atomic_path(vecnormalize) as tmp:
            vecnorm.save(str(tmp))
