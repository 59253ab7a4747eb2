"""A finished run's checkpoint without what only further training needs: the optimizers' moments.

A run's final model (``model.safetensors`` + ``model.json``) keeps the Adam moments of its optimizers so that
it can be trained on. A committed result is never trained on (a fine-tuning run takes the policy's weights
only, :func:`~softpvtol_gym.baselines.training.imitation.init_from_run`), and the moments are two thirds of the
file. :func:`compact_checkpoint` drops them: the optimizer keeps its parameter groups, with no per-parameter
state (an optimizer loaded from it starts with fresh moments, as a new one does). The policy, the value net,
the normalisation statistics and the config are kept byte for byte, so every evaluation replays unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path

from softpvtol_gym.baselines.checkpoints.manifest import (
    MANIFEST_FILE,
    MODEL_FILE,
    MODEL_STATE_FILE,
    read_manifest,
    read_verified,
    write_manifest,
)
from softpvtol_gym.baselines.checkpoints.model_state import sorted_metadata
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.util.atomic import atomic_write_bytes, atomic_write_text


def optimizer_tensors(names, meta: dict) -> list[str]:
    """The tensor names among ``names`` that are an optimizer's per-parameter state (``<optimizer>/state/...``
    for each optimizer of model.json's ``optimizers``)."""
    prefixes = tuple(f"{name}/state/" for name in meta.get("optimizers", {}))
    return sorted(n for n in names if prefixes and n.startswith(prefixes))


def compact_checkpoint(folder: Path) -> bool:
    """Drop the optimizers' state from the checkpoint in ``folder`` (verified first) and rewrite its manifest;
    False if it holds none (then nothing is written). CheckpointError for a folder that does not verify."""
    from safetensors import SafetensorError
    from safetensors.numpy import load, save

    folder = Path(folder)
    manifest = read_manifest(folder)
    data = read_verified(folder, manifest, MODEL_FILE)
    meta = json.loads(read_verified(folder, manifest, MODEL_STATE_FILE))
    try:
        tensors = load(data)
    except (SafetensorError, ValueError) as exc:
        raise CheckpointError(f"{folder / MODEL_FILE} is not a readable safetensors file ({exc})") from None
    dropped = optimizer_tensors(tensors, meta)
    stateful = [name for name, o in meta.get("optimizers", {}).items() if o.get("params_with_state")]
    if not dropped and not stateful:
        return False
    header = json.loads(data[8:8 + int.from_bytes(data[:8], "little")])
    kept = {k: v for k, v in tensors.items() if k not in set(dropped)}
    atomic_write_bytes(folder / MODEL_FILE, sorted_metadata(save(kept, metadata=header.get("__metadata__"))))
    for optimizer in meta.get("optimizers", {}).values():
        optimizer["scalar_state"], optimizer["params_with_state"] = {}, []
    atomic_write_text(folder / MODEL_STATE_FILE, json.dumps(meta, indent=1))
    write_manifest(folder, list(manifest["files"]), manifest["algo"], manifest["num_timesteps"], manifest["kind"])
    return True


def checkpoint_folders(root: Path) -> list[Path]:
    """Every folder under ``root`` (itself included) that is a checkpoint (holds a manifest), sorted."""
    return sorted(p.parent for p in Path(root).rglob(MANIFEST_FILE))
