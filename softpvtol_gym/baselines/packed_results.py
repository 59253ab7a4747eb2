"""The committed results as archives, and the folders they unpack to.

The per-episode detail and the trained runs are most of the results by size and by file count. They are
committed packed, under ``<results>/archive/``:

- each job folder of ``leaderboard_runs/``, ``ablation_runs/`` and ``distill_runs/`` as one reproducible
  ``.tar.xz`` (``archive/leaderboard_runs/<job>.tar.xz`` holds ``leaderboard_runs/<job>/``);
- ``leaderboard.json`` as ``archive/leaderboard.json.xz``, in its thin form
  (:mod:`~softpvtol_gym.baselines.util.shared_lists`): its per-episode metrics are those of the jobs'
  ``eval.json``, so the archive refers to them there, and unpacking rebuilds the file byte for byte (checked
  against its sha256) once the job folders are unpacked.

:func:`unpack` writes the folders and files back where the commands read and write them (``leaderboard_runs/...``
and ``leaderboard.json`` are not tracked: they are built from the archives); :func:`pack` writes the archives
of what the commands wrote, first dropping the optimizers' state from each finished checkpoint, and the critic
from each finished PPO run but the distilled students (:mod:`~softpvtol_gym.baselines.checkpoints.compact`);
:func:`differences` lists where the two disagree. Which
archive an unpacked folder came from is recorded in ``<results>/.unpacked.json`` (sha256 of each archive), so
that an unpack after ``git pull`` replaces exactly the folders whose archive changed, and never a folder that
no archive wrote (a job run here and not packed yet) unless asked to.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from filelock import FileLock

from softpvtol_gym.baselines.checkpoints.compact import checkpoint_folders, compact_checkpoint
from softpvtol_gym.baselines.util.archive import (
    ArchiveError,
    archive_members,
    folder_files,
    pack_file,
    pack_files,
    unpack_file,
)
from softpvtol_gym.baselines.util.atomic import atomic_dir, atomic_write_bytes, atomic_write_text
from softpvtol_gym.baselines.util.shared_lists import RebuildError, is_thin, thick, thin

ARCHIVE_DIR = "archive"
#: the folders of the results whose sub-folders are archived one by one
PACKED_FOLDERS = ("leaderboard_runs", "ablation_runs", "distill_runs")
#: the files of the results archived on their own
PACKED_FILES = ("leaderboard.json",)
#: the record a distilled student's checkpoint folder holds (softpvtol distill's)
DISTILL_RECORD = "distill.json"
#: which archive each unpacked folder or file came from (not tracked), and the lock that one unpack at a time holds
RECORD_FILE, LOCK_FILE = ".unpacked.json", ".unpack.lock"
FOLDER_SUFFIX, FILE_SUFFIX = ".tar.xz", ".xz"
#: a packed file -> (the folder, the file name) of the JSON files whose lists its thin form refers to
SHARED_SOURCES = {"leaderboard.json": ("leaderboard_runs", "eval.json")}


@dataclasses.dataclass(frozen=True)
class Packed:
    """One archive and what it unpacks to: ``target`` (a folder for ``.tar.xz``, a file for ``.xz``), both under
    the results folder; ``key``: the archive's path relative to it (the record's key)."""

    archive: Path
    target: Path
    key: str

    @property
    def is_folder(self) -> bool:
        return self.archive.name.endswith(FOLDER_SUFFIX)


def _packed(results: Path, relative: str, is_folder: bool) -> Packed:
    key = f"{ARCHIVE_DIR}/{relative}{FOLDER_SUFFIX if is_folder else FILE_SUFFIX}"
    return Packed(results / key, results / relative, key)


def archives(results: Path) -> list[Packed]:
    """Every committed archive under ``results``, sorted."""
    results = Path(results)
    out = [_packed(results, f"{family}/{a.name[:-len(FOLDER_SUFFIX)]}", True)
           for family in PACKED_FOLDERS for a in sorted((results / ARCHIVE_DIR / family).glob(f"*{FOLDER_SUFFIX}"))]
    out += [_packed(results, name, False) for name in PACKED_FILES
            if (results / ARCHIVE_DIR / f"{name}{FILE_SUFFIX}").is_file()]
    return out


def packable(results: Path) -> list[Packed]:
    """Every job folder and file under ``results`` that has (or should have) an archive, sorted."""
    results = Path(results)
    out = [_packed(results, f"{family}/{d.name}", True) for family in PACKED_FOLDERS
           for d in sorted((results / family).iterdir() if (results / family).is_dir() else ())
           if d.is_dir() and not d.name.startswith(".")]
    out += [_packed(results, name, False) for name in PACKED_FILES if (results / name).is_file()]
    return out


def kept_files(folder: Path) -> dict[str, bytes]:
    """The files of a job folder that are packed: all but hidden ones (locks, temporaries), a job's training
    folder while it runs (``*.run/``) and a distilled run's cached datasets (``datasets/``, collected again)."""
    return {name: data for name, data in folder_files(folder).items()
            if not any(p.startswith(".") or p.endswith(".run") or p == "datasets" for p in name.split("/"))}


def _source_names(results: Path, name: str) -> list[str]:
    """The names (relative to ``results``) of the files that ``name``'s thin form may refer to."""
    folder, file = SHARED_SOURCES.get(name, (None, None))
    if folder is None or not (results / folder).is_dir():
        return []
    return sorted(p.relative_to(results).as_posix() for p in (results / folder).rglob(file)
                  if not any(part.startswith(".") or part.endswith(".run") for part in p.relative_to(results).parts))


def _packed_file_bytes(results: Path, p: Packed) -> bytes:
    """What the archive of the file ``p`` holds: its thin form where it has one, else its bytes."""
    data = p.target.read_bytes()
    names = _source_names(results, p.target.name)
    thinned = thin(data, {n: (results / n).read_bytes() for n in names}) if names else None
    return data if thinned is None else thinned


def _unpacked_file_bytes(results: Path, p: Packed, data: bytes) -> bytes:
    """The file that the archive ``data`` of ``p`` unpacks to (a thin form rebuilt from the unpacked job folders);
    ArchiveError where it cannot be."""
    content = unpack_file(data, p.key)
    if not is_thin(content):
        return content
    allowed = set(_source_names(results, p.target.name))

    def read(name: str) -> bytes:
        if name not in allowed:  # only the files it may refer to, never a path of the archive's choosing
            raise KeyError(name)
        return (results / name).read_bytes()

    try:
        return thick(content, read)
    except (RebuildError, ValueError, TypeError, KeyError) as exc:
        raise ArchiveError(f"{p.key} does not rebuild {p.target.name} from the unpacked job folders ({exc}); "
                           "unpack --force replaces folders of other versions") from None


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _records(results: Path) -> dict[str, str]:
    try:
        data = json.loads((Path(results) / RECORD_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write_records(results: Path, records: dict[str, str]) -> None:
    atomic_write_text(Path(results) / RECORD_FILE, json.dumps(dict(sorted(records.items())), indent=1) + "\n")


def unpack(results: Path, force: bool = False) -> tuple[list[Packed], list[Packed]]:
    """Write every archive's folder or file under ``results`` where it is missing or came from another version
    of the archive (``force``: also where it was not unpacked from an archive). Returns (what was unpacked,
    what was kept because no archive wrote it). ArchiveError for an archive that does not read."""
    results = Path(results)
    with FileLock(str(results / LOCK_FILE)):  # parallel test workers and scripts unpack one at a time
        return _unpack(results, force)


def _unpack(results: Path, force: bool) -> tuple[list[Packed], list[Packed]]:
    records = _records(results)
    done, kept = [], []
    for p in archives(results):
        data = p.archive.read_bytes()
        sha = _sha256(data)
        present = p.target.exists()
        if present and records.get(p.key) == sha:
            continue
        if present and p.key not in records and not force:
            kept.append(p)
            continue
        if p.is_folder:
            members = archive_members(data, str(p.archive))
            with atomic_dir(p.target) as tmp:
                for name, content in members.items():
                    (tmp / name).parent.mkdir(parents=True, exist_ok=True)
                    (tmp / name).write_bytes(content)
        else:
            atomic_write_bytes(p.target, _unpacked_file_bytes(results, p, data))
        records[p.key] = sha
        done.append(p)
    if done:
        _write_records(results, records)
    return done, kept


def pack(results: Path) -> list[Packed]:
    """Write the archive of every job folder and packed file under ``results`` whose archive is missing or
    differs, after compacting the folder's finished checkpoints; remove the archives of job folders that are
    gone. Returns the archives written or removed."""
    results = Path(results)
    records = _records(results)
    changed = []
    targets = packable(results)
    for p in targets:
        if p.is_folder:
            for folder in checkpoint_folders(p.target):
                inside = folder.relative_to(p.target).parts  # a run still training keeps its optimizer
                if not any(part.endswith(".run") or part == "checkpoints" for part in inside):
                    # a distilled student keeps its critic: fine-tuning runs start from it, critic included
                    compact_checkpoint(folder, drop_value_function=not (folder / DISTILL_RECORD).is_file())
            data = pack_files(kept_files(p.target))
        else:
            data = pack_file(_packed_file_bytes(results, p))
        if not p.archive.is_file() or p.archive.read_bytes() != data:
            atomic_write_bytes(p.archive, data)
            changed.append(p)
        records[p.key] = _sha256(data)
    wanted = {p.key for p in targets}
    for p in archives(results):
        if p.key not in wanted:
            p.archive.unlink()
            records.pop(p.key, None)
            changed.append(p)
    _write_records(results, records)
    return changed


def differences(results: Path) -> list[str]:
    """Where the archives under ``results`` and the folders and files they unpack to disagree, in words (empty:
    they agree): an archive not unpacked, a file that differs, is missing or is extra, a job folder without an
    archive."""
    results = Path(results)
    out = []
    committed = archives(results)
    for p in committed:
        if not p.target.exists():
            out.append(f"{p.target} is missing (unpack {p.key})")
            continue
        data = p.archive.read_bytes()
        try:
            if p.is_folder:
                want, have = archive_members(data, p.key), kept_files(p.target)
                for name in sorted(set(want) | set(have)):
                    if name not in have:
                        out.append(f"{p.target / name} is missing (it is in {p.key})")
                    elif name not in want:
                        out.append(f"{p.target / name} is not in {p.key} (pack it)")
                    elif want[name] != have[name]:
                        out.append(f"{p.target / name} differs from {p.key}")
            elif _unpacked_file_bytes(results, p, data) != p.target.read_bytes():
                out.append(f"{p.target} differs from {p.key}")
        except ArchiveError as exc:
            out.append(str(exc))
    known = {p.key for p in committed}
    out += [f"{p.target} has no archive {p.key} (pack it)" for p in packable(results) if p.key not in known]
    return out
