"""Checkpoints that cannot run code: weights in safetensors, everything else in JSON / npz.

A checkpoint is a folder. A finished run directory is one (its final model), and so is every
``<run>/checkpoints/step_<NNNNNNNNNN>/`` taken during training. Files:

* ``model.safetensors``   every tensor of the SB3 model: the policy's ``state_dict`` (``policy/...``), the
  optimizers' state (``<optimizer>/state/<i>/<key>``), SB3's extra torch variables (``variables/...``,
  SAC's entropy coefficient) and the model's last observation arrays (``attributes/...``);
* ``model.json``          the rest of the model's training state: algorithm, counters (``num_timesteps``,
  ``_n_updates``, ...), the optimizers' parameter groups, the episode-info buffer, the RNG states of the
  action and observation spaces;
* ``vecnormalize.json``   the VecNormalize settings and running statistics (absent without normalisation);
* ``config.yaml``         the run's :class:`~softpvtol_gym.baselines.config.run_config.RunConfig` (the network
  is rebuilt from it);
* ``resume_state.json`` + ``resume_state.npz``  (training checkpoints) what an exact resume needs
  besides: every array of the vector env (each sub-env mid-episode, the residual controller's memory),
  the sub-envs' generator states, VecNormalize's running returns, the numpy / torch / python RNG states;
* ``replay_buffer.npz`` + ``replay_buffer.json``  (off-policy algorithms) the filled part of the replay
  buffer and its position;
* ``checkpoint.json``     the manifest, written last: format version, algorithm, step count and the
  SHA-256 and size of every file above. A folder without a manifest that verifies is not a checkpoint.

Loading never unpickles: safetensors and JSON hold data only, ``np.load`` runs with
``allow_pickle=False``, and the model is rebuilt from ``config.yaml`` before its weights are filled in.
Files with other names (a ``model.zip`` or ``*.pkl`` planted next to them) are ignored; pickle-based
files are read only through :mod:`softpvtol_gym.baselines.checkpoints.sb3_compat` with an explicit ``trust_pickle``.

Training checkpoints are written into a temporary folder that is fsync'ed and renamed into place;
``checkpoints/latest`` (the step folder's name) is then replaced atomically, and the newest ``keep`` are
kept. A process killed at any moment leaves the previous or the new checkpoint, never a half-written
one; a checkpoint that does not verify (a bad disk, an edit) is skipped in favour of the previous one.
Checkpoints are taken at rollout boundaries (after a PPO update, before the next rollout), so resuming
continues with exactly the steps that were not yet trained on; for PPO on this env the resumed run is
bit for bit the uninterrupted one (tested).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

from softpvtol_gym.baselines.checkpoints.manifest import (
    CONFIG_FILE,
    LATEST,
    LEGACY_FILES,
    MANIFEST_FILE,
    MODEL_FILE,
    MODEL_STATE_FILE,
    STEP_RE,
    read_manifest,
    read_verified,
    step_dir_name,
    write_manifest,
)
from softpvtol_gym.baselines.checkpoints.model_state import save_model, save_vecnorm
from softpvtol_gym.baselines.checkpoints.resume import save_replay_buffer, save_resume_state
from softpvtol_gym.baselines.config.run_config import RunConfig
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.util.atomic import (
    atomic_dir,
    atomic_write_text,
    clean_stale_temps,
    fsync_dir,
    temp_name,
)


# ---------------------------------------------------------------------------------- checkpoints
def write_model_files(folder: Path, model, vecnorm, config: RunConfig, kind: str) -> None:
    """The model files and, last, the manifest (a run's final model, or the model part of a checkpoint)."""
    folder = Path(folder)
    names = save_model(model, folder)
    if vecnorm is not None:
        names += save_vecnorm(vecnorm, folder)
    if not (folder / CONFIG_FILE).is_file() or RunConfig.load(folder / CONFIG_FILE) != config:
        config.save(folder / CONFIG_FILE)
    names.append(CONFIG_FILE)
    write_manifest(folder, names, config.algo, model.num_timesteps, kind)


def save_checkpoint(run_dir: Path, model, vecnorm, config: RunConfig, keep: int = 2) -> Path:
    """Write a checkpoint of ``model`` (on ``vecnorm`` over the SB3 adapter) atomically; keep the newest
    ``keep`` checkpoints. Returns the checkpoint directory."""
    root = Path(run_dir) / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    name = step_dir_name(int(model.num_timesteps))
    final = root / name
    if not _verifies(final):  # the same step again (a resumed run's first boundary): keep the existing one
        with atomic_dir(final) as tmp:
            names = save_model(model, tmp)
            if vecnorm is not None:
                names += save_vecnorm(vecnorm, tmp)
            config.save(tmp / CONFIG_FILE)
            names += [CONFIG_FILE, *save_resume_state(model, vecnorm, tmp)]
            replay = {}
            if getattr(model, "replay_buffer", None) is not None:  # off-policy algorithms (SAC)
                files, replay = save_replay_buffer(model.replay_buffer, tmp)
                names += files
            if replay:
                atomic_write_text(tmp / "replay_buffer.json", json.dumps(replay))
                names.append("replay_buffer.json")
            write_manifest(tmp, names, config.algo, model.num_timesteps, "checkpoint")
    atomic_write_text(root / LATEST, name)
    for old in sorted(p for p in root.glob("step_*") if p.is_dir() and STEP_RE.match(p.name))[:-keep]:
        remove_dir(old)
    fsync_dir(root)
    return final


def remove_dir(path: Path) -> None:
    """Remove a directory so that a process killed meanwhile leaves no half-deleted folder under its name:
    it is renamed to a temporary name first (removed by the next start if the removal is interrupted)."""

    tmp = temp_name(path)
    try:
        os.replace(path, tmp)
    except FileNotFoundError:
        return
    shutil.rmtree(tmp, ignore_errors=True)


def _verifies(folder: Path) -> bool:
    try:
        manifest = read_manifest(folder)
        for name in manifest["files"]:
            read_verified(folder, manifest, name)
        return True
    except CheckpointError:
        return False


def checkpoint_candidates(run_dir: Path) -> list[Path]:
    """A run's training checkpoint folders, newest first: the one ``checkpoints/latest`` names (if it
    is a valid step name), then every other ``step_*`` folder by step. Nothing is verified yet."""
    root = Path(run_dir) / "checkpoints"
    out = []
    pointer = root / LATEST
    if pointer.is_file():
        try:
            name = pointer.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError):
            name = ""
        if STEP_RE.match(name) and (root / name).is_dir():
            out.append(root / name)
    for p in sorted((p for p in root.glob("step_*") if STEP_RE.match(p.name) and p.is_dir()), reverse=True):
        if p not in out:
            out.append(p)
    return out


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest training checkpoint of a run that verifies against its manifest, or None."""
    for cand in checkpoint_candidates(run_dir):
        if _verifies(cand):
            return cand
    return None


def clean_run_dir(run_dir: Path) -> None:
    """Remove what killed writers left in a run directory this process holds the lock of."""
    run_dir = Path(run_dir)
    clean_stale_temps(run_dir, everything=True)
    clean_stale_temps(run_dir / "checkpoints", everything=True)


def legacy_files(folder: Path) -> list[str]:
    """Pickle-based files of earlier versions present in ``folder``."""
    return [n for n in LEGACY_FILES if (Path(folder) / n).is_file()]


def find_checkpoint(path: Path) -> Path:
    """The checkpoint folder that ``path`` names: a run directory (its final model, else its newest
    training checkpoint that verifies), a checkpoint folder, or a file inside one. CheckpointError, naming
    what was found, otherwise."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist (expected a run directory, a checkpoint directory "
                              f"or its {MODEL_FILE})")
    if path.is_file():
        if path.name in (MODEL_FILE, MANIFEST_FILE, MODEL_STATE_FILE):
            return path.parent
        if path.name in LEGACY_FILES or path.suffix in (".zip", ".pkl", ".pickle", ".pt", ".pth"):
            raise CheckpointError(f"{path} is a pickle-based file ({path.suffix}), which can run code when loaded; "
                                  f"this project loads checkpoints in its safe format only (docs/baselines.md, "
                                  f"'Loading checkpoints'). If you created it or trust its source, pass --trust-pickle "
                                  f"or convert it once with python baselines/export.py from-sb3 --trust-pickle")
        raise CheckpointError(f"{path} is not a checkpoint (a {path.stat().st_size}-byte file); expected a run "
                              f"directory, a checkpoint directory or its {MODEL_FILE}")
    if (path / MANIFEST_FILE).is_file():
        return path
    ck = latest_checkpoint(path)
    if ck is not None:
        return ck
    legacy = legacy_files(path)
    if legacy:
        raise CheckpointError(f"{path} holds only pickle-based files {legacy} (an earlier format, or SB3's), which "
                              f"can run code when loaded; pass --trust-pickle if you created them or trust their "
                              f"source, or convert them once with python baselines/export.py from-sb3 --trust-pickle "
                              f"{path}")
    if (path / MODEL_FILE).is_file():
        raise CheckpointError(f"{path} has {MODEL_FILE} but no {MANIFEST_FILE}: an interrupted save; resume the run "
                              f"to finish it")
    raise CheckpointError(f"{path} holds no checkpoint (no {MANIFEST_FILE}, no complete checkpoints/step_*)")


def warn(message: str) -> None:
    sys.stderr.write(f"warning: {message}\n")
