"""The checkpoint format: file names, the manifest (SHA-256 of every file) and JSON / npz helpers."""

from __future__ import annotations

import hashlib
import io
import json
import re
import zipfile
from pathlib import Path

import numpy as np

from softpvtol_gym.baselines.config.hyperparams import CONFIG_FILE_NAME
from softpvtol_gym.baselines.errors import CheckpointError
from softpvtol_gym.baselines.util.atomic import (
    atomic_write_text,
)
from softpvtol_gym.baselines.util.safe_load import UnsafeInputError, loads_json

FORMAT = "softpvtol-gym checkpoint"
FORMAT_VERSION = 1
LATEST = "latest"
MANIFEST_FILE = "checkpoint.json"
MODEL_FILE = "model.safetensors"
MODEL_STATE_FILE = "model.json"
VECNORM_FILE = "vecnormalize.json"
CONFIG_FILE = CONFIG_FILE_NAME
STATE_FILE = "resume_state.json"
STATE_ARRAYS_FILE = "resume_state.npz"
REPLAY_FILE = "replay_buffer.npz"
#: the files of the model itself (what evaluation reads), in the order they are written
MODEL_FILES = (MODEL_FILE, MODEL_STATE_FILE, VECNORM_FILE, CONFIG_FILE)
#: names of pickle-based files of earlier versions (and of SB3): never loaded without trust_pickle
LEGACY_FILES = ("model.zip", "vecnormalize.pkl", "resume_state.pkl", "replay_buffer.pkl")
STEP_RE = re.compile(r"^step_\d{10}$")
MAX_MANIFEST_BYTES = 2**20
#: model attributes saved in model.json (counters) and model.safetensors (arrays)
COUNTERS = ("num_timesteps", "_total_timesteps", "_num_timesteps_at_start", "_n_updates", "_episode_num",
            "_current_progress_remaining")
ARRAY_ATTRIBUTES = ("_last_obs", "_last_original_obs", "_last_episode_starts")
_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")


def step_dir_name(step: int) -> str:
    return f"step_{step:010d}"


# ---------------------------------------------------------------------------------------- manifest
def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_manifest(folder: Path, names: list[str], algo: str, num_timesteps: int, kind: str) -> None:
    """Write ``checkpoint.json`` over the files ``names`` of ``folder`` (last: it makes the folder a
    checkpoint)."""
    files = {}
    for name in names:
        data = (Path(folder) / name).read_bytes()
        files[name] = {"sha256": _sha256(data), "bytes": len(data)}
    manifest = {"format": FORMAT, "version": FORMAT_VERSION, "kind": kind, "algo": algo,
                "num_timesteps": int(num_timesteps), "files": files}
    atomic_write_text(Path(folder) / MANIFEST_FILE, json.dumps(manifest, indent=1))


def read_manifest(folder: Path) -> dict:
    """The verified manifest of a checkpoint folder; CheckpointError if it is missing, malformed, or a file it
    lists is missing or differs (size or SHA-256) from what was written."""
    folder = Path(folder)
    path = folder / MANIFEST_FILE
    if not path.is_file():
        raise CheckpointError(f"{folder} is not a checkpoint: no {MANIFEST_FILE}")
    try:
        size = path.stat().st_size
        if size > MAX_MANIFEST_BYTES:
            raise CheckpointError(f"{path} is {size:,} bytes; a manifest has at most {MAX_MANIFEST_BYTES:,}")
        data = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"{path} is not readable ({exc})") from None
    try:
        manifest = loads_json(data, "its text", allow_nan=False, max_bytes=MAX_MANIFEST_BYTES)
    except UnsafeInputError as exc:
        raise CheckpointError(f"{path} is not readable JSON ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} manifest")
    if manifest.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"{path} has format version {manifest.get('version')!r}; this softpvtol-gym reads "
                              f"version {FORMAT_VERSION}")
    files = manifest.get("files")
    if (not isinstance(files, dict) or not isinstance(manifest.get("num_timesteps"), int)
            or manifest.get("algo") not in ("ppo", "sac")):
        raise CheckpointError(f"{path} is malformed (expected files, algo and num_timesteps)")
    for name, entry in files.items():
        if not isinstance(name, str) or "/" in name or name.startswith(".") or not isinstance(entry, dict):
            raise CheckpointError(f"{path} lists an invalid file entry {name!r}")
        if not (folder / name).is_file():
            raise CheckpointError(f"checkpoint {folder} is incomplete: {name} is missing")
    return manifest


def read_verified(folder: Path, manifest: dict, name: str) -> bytes:
    """The bytes of ``name`` in a checkpoint folder, checked against its manifest entry."""
    entry = manifest["files"].get(name)
    if entry is None:
        raise CheckpointError(f"checkpoint {folder} has no {name} (its manifest does not list it)")
    path = Path(folder) / name
    size = entry.get("bytes")
    try:
        # the size first: a file that does not match is not read into memory
        if isinstance(size, bool) or not isinstance(size, int) or path.stat().st_size != size:
            raise CheckpointError(f"{path} is corrupt or was changed after it was written: its size does not match "
                                  f"{MANIFEST_FILE}")
        data = path.read_bytes()
    except OSError as exc:
        raise CheckpointError(f"cannot read {path}: {exc}") from None
    if len(data) != size or _sha256(data) != entry.get("sha256"):
        raise CheckpointError(f"{path} is corrupt or was changed after it was written: its size or SHA-256 does "
                              f"not match {MANIFEST_FILE}")
    return data


def read_json(folder: Path, manifest: dict, name: str):
    data = read_verified(folder, manifest, name)
    return loads_json(data, str(Path(folder) / name), error=CheckpointError, allow_nan=False)


def read_npz(folder: Path, manifest: dict, name: str) -> dict[str, np.ndarray]:
    data = read_verified(folder, manifest, name)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, MemoryError, zipfile.BadZipFile) as exc:
        raise CheckpointError(f"{Path(folder) / name} is not a readable npz archive ({type(exc).__name__}: "
                              f"{str(exc)[:200]})") from None


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# ------------------------------------------------------------------------------- JSON helpers
def to_json(value):
    """Tuples survive a JSON round trip (optimizer parameter groups hold ``betas`` tuples)."""
    if isinstance(value, tuple):
        return {"__tuple__": [to_json(v) for v in value]}
    if isinstance(value, list):
        return [to_json(v) for v in value]
    if isinstance(value, dict):
        return {k: to_json(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def from_json(value):
    if isinstance(value, dict):
        if set(value) == {"__tuple__"}:
            return tuple(from_json(v) for v in value["__tuple__"])
        return {k: from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json(v) for v in value]
    return value


def generator_state(gen) -> dict | None:
    return None if gen is None else to_json(gen.bit_generator.state)


def generator_from_state(state: dict, what: str):
    if not isinstance(state, dict) or state.get("bit_generator") not in _BIT_GENERATORS:
        raise CheckpointError(f"{what}: unknown random generator state {str(state)[:80]!r}")
    gen = np.random.Generator(getattr(np.random, state["bit_generator"])())
    try:
        gen.bit_generator.state = from_json(state)
    except (TypeError, ValueError, KeyError, OverflowError) as exc:  # Overflow: an integer outside 0 .. 2**128-1
        raise CheckpointError(f"{what}: invalid random generator state ({exc})") from None
    return gen
