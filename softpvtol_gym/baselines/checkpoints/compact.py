"""A finished run's checkpoint without what only further training needs: the optimizers' moments, and the critic.

A run's final model (``model.safetensors`` + ``model.json``) keeps the Adam moments of its optimizers so that
it can be trained on. A committed result is never trained on, and the moments are two thirds of the file.
:func:`compact_checkpoint` drops them: the optimizer keeps its parameter groups, with no per-parameter state (an
optimizer loaded from it starts with fresh moments, as a new one does). With ``drop_value_function`` it also
drops a PPO policy's value function (its critic, about half of a 64 x 64 policy's weights): model.json lists the
tensors dropped (``tensors_dropped``), and a model loaded from it has the critic a new model of the run's config
and seed starts with, so that fine-tuning from it starts a critic afresh. The packed results drop it from every
finished PPO run but the distilled students (the fine-tuning cells start from a student, critic included). The
actor, the normalisation statistics and the config are kept byte for byte, so every evaluation replays unchanged.
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
from softpvtol_gym.baselines.checkpoints.model_state import DROPPED_KEY, sorted_metadata
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.util.atomic import atomic_write_bytes, atomic_write_text


def optimizer_tensors(names, meta: dict) -> list[str]:
    """The tensor names among ``names`` that are an optimizer's per-parameter state (``<optimizer>/state/...``
    for each optimizer of model.json's ``optimizers``)."""
    prefixes = tuple(f"{name}/state/" for name in meta.get("optimizers", {}))
    return sorted(n for n in names if prefixes and n.startswith(prefixes))


def value_function_tensors(names, meta: dict) -> list[str]:
    """The tensor names among ``names`` that are a PPO policy's value function (its critic); [] for other
    algorithms."""
    if meta.get("algo") != "ppo":
        return []
    return sorted(n for n in names if n.startswith(("policy/value_net.", "policy/mlp_extractor.value_net.")))


def compact_checkpoint(folder: Path, drop_value_function: bool = False) -> bool:
    """Drop the optimizers' state (and, with ``drop_value_function``, a PPO policy's critic) from the checkpoint
    in ``folder`` (verified first) and rewrite its manifest; False if it holds none (then nothing is written).
    CheckpointError for a folder that does not verify."""
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
    critic = value_function_tensors(tensors, meta) if drop_value_function else []
    stateful = [name for name, o in meta.get("optimizers", {}).items() if o.get("params_with_state")]
    if not dropped and not stateful and not critic:
        return False
    header = json.loads(data[8:8 + int.from_bytes(data[:8], "little")])
    kept = {k: v for k, v in tensors.items() if k not in set(dropped) | set(critic)}
    if critic:
        meta[DROPPED_KEY] = sorted({*meta.get(DROPPED_KEY, []), *critic})
    atomic_write_bytes(folder / MODEL_FILE, sorted_metadata(save(kept, metadata=header.get("__metadata__"))))
    for optimizer in meta.get("optimizers", {}).values():
        optimizer["scalar_state"], optimizer["params_with_state"] = {}, []
    atomic_write_text(folder / MODEL_STATE_FILE, json.dumps(meta, indent=1))
    write_manifest(folder, list(manifest["files"]), manifest["algo"], manifest["num_timesteps"], manifest["kind"])
    return True


def checkpoint_folders(root: Path) -> list[Path]:
    """Every folder under ``root`` (itself included) that is a checkpoint (holds a manifest), sorted."""
    return sorted(p.parent for p in Path(root).rglob(MANIFEST_FILE))
