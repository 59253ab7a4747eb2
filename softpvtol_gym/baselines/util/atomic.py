"""One way to write a result file: atomically and durably.

Every file the project writes as a result (models, configs, JSON, Markdown, figures) goes through
:func:`atomic_path`: the content is written to a temporary file in the same directory, flushed and
fsync'ed, renamed over the target with ``os.replace`` (atomic on POSIX file systems), and the directory
is fsync'ed so that the rename itself survives a crash. A reader sees the old file or the new one,
never a partial one; a process killed half-way leaves at most a temporary file, which
:func:`clean_stale_temps` removes on the next start (temporary names carry the writer's pid).

Standard library only (``benchmarks/run.py`` uses it without the ``baselines`` extra).
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

#: temporary files and directories: ``.<target name>.<pid>.<random>.tmp``
_TMP_RE = re.compile(r"^\..+\.(\d+)\.[0-9a-f]{8}\.tmp$")
#: temporary checkpoint directories of earlier versions: ``.tmp_step_<N>_<pid>``
_LEGACY_TMP_RE = re.compile(r"^\.tmp_step_\d+_(\d+)$")


def temp_name(path: Path) -> Path:
    """A fresh temporary sibling of ``path`` (same directory, so that ``os.replace`` is a rename)."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def fsync_dir(directory: Path) -> None:
    """fsync a directory (makes renames and new entries in it durable); a no-op where unsupported."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            _fsync_file(Path(dirpath) / name)
        fsync_dir(Path(dirpath))


@contextlib.contextmanager
def atomic_path(path: Path, mkdir: bool = True) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s new content to; on a normal exit it becomes ``path``.

        with atomic_path(out / "figure.png") as tmp:
            fig.savefig(tmp, format="png")

    On an exception the temporary file is removed and ``path`` is left as it was."""
    path = Path(path)
    if mkdir:
        path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temps(path.parent, name=path.name)
    tmp = temp_name(path)
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        _name_the_target(exc, path)
        raise
    fsync_dir(path.parent)


def _name_the_target(exc: BaseException, path: Path) -> None:
    """Give an OSError without a file name (a full disk met by ``write``, ``flush`` or ``fsync``) the target's
    path, so that the command's one-line message names the file it could not write."""
    if isinstance(exc, OSError) and exc.filename is None:
        exc.filename = str(path)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically and durably."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically and durably."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_all(files: dict) -> None:
    """Write several files, all or nothing as far as POSIX allows: ``files`` maps each path to its bytes. Every
    content is first written and fsync'ed to a temporary sibling; only when all of them are written (a full disk
    or a read-only directory fails here, with every target unchanged) are they renamed over their targets, one
    ``os.replace`` each."""
    temps: list[tuple[Path, Path]] = []
    try:
        for path, data in files.items():
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            clean_stale_temps(path.parent, name=path.name)
            tmp = temp_name(path)
            temps.append((tmp, path))
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
    except BaseException as exc:
        for tmp, _ in temps:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        if temps:
            _name_the_target(exc, temps[-1][1])
        raise
    for tmp, path in temps:
        os.replace(tmp, path)
    for parent in {path.parent for _, path in temps}:
        fsync_dir(parent)


def atomic_copy(src: Path, dst: Path) -> None:
    """Copy the bytes of ``src`` to ``dst`` atomically and durably."""
    atomic_write_bytes(dst, Path(src).read_bytes())


@contextlib.contextmanager
def atomic_dir(path: Path) -> Iterator[Path]:
    """Yield a temporary directory that, on a normal exit, is fsync'ed and renamed to ``path`` (which must
    not exist then, or be a directory that is replaced: it is removed first). On an exception the
    temporary directory is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_name(path)
    tmp.mkdir()
    try:
        yield tmp
        _fsync_tree(tmp)
        if path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fsync_dir(path.parent)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def clean_stale_temps(directory: Path, name: str | None = None, everything: bool = False) -> list[Path]:
    """Remove temporary files/directories left in ``directory`` by killed writers: those whose pid is
    no longer running (all of them with ``everything=True``: for a directory this process holds the lock
    of, none can be in use), only those of target ``name`` if given. Returns what was removed."""
    directory = Path(directory)
    removed = []
    try:
        entries = list(directory.iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for p in entries:
        m = _TMP_RE.match(p.name) or _LEGACY_TMP_RE.match(p.name)
        if m is None:
            continue
        if name is not None and not p.name.startswith(f".{name}."):
            continue
        pid = int(m.group(1))
        if not everything and _alive(pid):
            continue
        if everything and pid == os.getpid():
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
        removed.append(p)
    return removed
