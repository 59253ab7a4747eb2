"""Folders and files as reproducible xz archives, and archives read back without trusting them.

:func:`pack_files` writes a folder's files (:func:`folder_files`) as a ``.tar.xz`` whose bytes depend on the files'
names and contents only (sorted members, no times, owners or modes), so that packing the same folder twice gives the
same archive and git sees a change only where a file changed. :func:`archive_members` reads an archive back as
``{relative name: bytes}``, refusing what a packed folder never holds (links, devices, absolute names, ``..``, more
than :data:`MAX_UNPACKED_BYTES`), so an archive is data: nothing in it is run and nothing lands outside the folder
it is unpacked into. A single file is packed as plain ``.xz``.
"""

from __future__ import annotations

import io
import lzma
import tarfile
from pathlib import Path, PurePosixPath

from softpvtol_gym.baselines.errors import ConfigError

#: the most an archive may unpack to (the committed ones unpack to a few MB each)
MAX_UNPACKED_BYTES = 2**30
#: xz's preset: the strongest (a 64 MiB window; unpacking needs about as much memory)
PRESET = 9


class ArchiveError(ConfigError):
    """An archive that is not one of this module's: not xz, not tar, or holding what a packed folder cannot."""


def folder_files(folder: Path) -> dict[str, bytes]:
    """{name relative to ``folder`` (POSIX separators): bytes} of every regular file under it, sorted; symlinks
    are refused (a packed folder holds files only)."""
    folder = Path(folder)
    out = {}
    for path in sorted(folder.rglob("*")):
        if path.is_symlink():
            raise ArchiveError(f"{path} is a symbolic link; an archived folder holds regular files only")
        if path.is_file():
            out[path.relative_to(folder).as_posix()] = path.read_bytes()
    return out


def pack_files(files: dict[str, bytes]) -> bytes:
    """A ``.tar.xz`` of ``files`` ({relative name: bytes}), the same bytes for the same files."""
    buffer = io.BytesIO()
    with tarfile.TarFile(fileobj=buffer, mode="w", format=tarfile.GNU_FORMAT) as tar:  # in memory
        for name in sorted(files):
            info = tarfile.TarInfo(_checked_name(name))
            info.size, info.mode, info.mtime = len(files[name]), 0o644, 0
            tar.addfile(info, io.BytesIO(files[name]))
    return pack_file(buffer.getvalue())


def pack_file(data: bytes) -> bytes:
    """The ``.xz`` of one file's bytes ``data`` (the same bytes for the same data)."""
    return lzma.compress(data, format=lzma.FORMAT_XZ, preset=PRESET)


def archive_members(data: bytes, source: str) -> dict[str, bytes]:
    """{relative name: bytes} of the ``.tar.xz`` ``data``; ArchiveError naming ``source`` for anything but
    regular files and folders under relative names without ``..``, or more than :data:`MAX_UNPACKED_BYTES`."""
    raw = unpack_file(data, source)
    out: dict[str, bytes] = {}
    try:
        with tarfile.open(fileobj=io.BytesIO(raw), mode="r:") as tar:
            for member in tar:
                if member.isdir():
                    continue
                if not member.isfile():
                    raise ArchiveError(f"{source}: member {member.name!r} is not a regular file (a link or a "
                                       f"device); an archived folder holds files only")
                name = _checked_name(member.name, source)
                out[name] = tar.extractfile(member).read()
    except tarfile.TarError as exc:
        raise ArchiveError(f"{source} is not a tar archive inside its xz ({exc})") from None
    return out


def unpack_file(data: bytes, source: str) -> bytes:
    """The bytes of the ``.xz`` ``data``; ArchiveError naming ``source`` if it is not xz or unpacks to more than
    :data:`MAX_UNPACKED_BYTES`."""
    decompressor = lzma.LZMADecompressor(format=lzma.FORMAT_XZ)
    try:
        raw = decompressor.decompress(data, max_length=MAX_UNPACKED_BYTES + 1)
    except lzma.LZMAError as exc:
        raise ArchiveError(f"{source} is not an xz file ({exc})") from None
    if len(raw) > MAX_UNPACKED_BYTES:
        raise ArchiveError(f"{source} unpacks to more than {MAX_UNPACKED_BYTES:,} bytes")
    if not decompressor.eof:
        raise ArchiveError(f"{source} is truncated (its xz stream does not end)")
    return raw


def _checked_name(name: str, source: str = "archive") -> str:
    path = PurePosixPath(name)
    if not name or path.is_absolute() or ".." in path.parts or "\\" in name or "\x00" in name:
        raise ArchiveError(f"{source}: member name {name!r} is not a relative path inside the folder")
    return path.as_posix()
