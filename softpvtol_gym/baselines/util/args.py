"""Command-line plumbing shared by the subcommands: one-line errors with exit code 2, never a traceback for
input a user can fix.

Exit codes of every command (:data:`EXIT_CODES`; the commands' help and docs/baselines.md list them):
0 done; 2 bad input (nothing started) or jobs that failed; 74 an input/output error (disk full, a read-only or
unwritable path: the message names the path; files are written atomically, so what was there stays whole);
130 interrupted by Ctrl-C (SIGINT), 143 by SIGTERM (the message says what was kept).

:class:`Parser` is an ``argparse.ArgumentParser`` whose errors are one line (``prog: error: ...``) and exit 2;
:func:`run_main` runs a command's body and turns a :class:`~softpvtol_gym.baselines.errors.ConfigError` (bad
input, an unusable checkpoint, a busy run directory) into the same one-line exit 2, and Ctrl-C into exit 130;
:func:`command_main` makes a subcommand's ``main`` of its body (once, for all of them). Also the argparse value
types, the output-file check made before any work, and reading a command's JSON report.
"""

from __future__ import annotations

import argparse
import errno
import math
import os
import signal
import sys
import tempfile
import threading
from pathlib import Path

from softpvtol_gym.baselines.errors import (  # noqa: F401  (the exit codes are re-exported)
    EXIT_BAD_INPUT,
    EXIT_IO_ERROR,
    EXIT_OK,
    EXIT_SIGINT,
    EXIT_SIGTERM,
    ConfigError,
)
from softpvtol_gym.baselines.util.extras import require
from softpvtol_gym.baselines.util.paths import Layout
from softpvtol_gym.baselines.util.safe_load import loads_json


def one_line(message: str) -> str:
    return " ".join(str(message).split())


def fail(prog: str, message: str, code: int = 2):
    sys.stderr.write(f"{prog}: error: {one_line(message)}\n")
    sys.stderr.flush()
    raise SystemExit(code)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``prog: error: message (see prog --help)``), exit code 2; the help ends
    with the exit codes (:data:`EXIT_EPILOG`)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("epilog", EXIT_EPILOG)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D401 (argparse API)
        fail(self.prog, f"{message} (see {self.prog} --help)")


#: exit codes of every command
EXIT_CODES = {EXIT_OK: "done", EXIT_BAD_INPUT: "bad input (one line, nothing started) or failed jobs",
              EXIT_IO_ERROR: "input/output error: disk full, a read-only or unwritable path (one line naming it)",
              EXIT_SIGINT: "interrupted by Ctrl-C (SIGINT)", EXIT_SIGTERM: "terminated by SIGTERM"}
#: the epilog of every command's --help
EXIT_EPILOG = ("exit codes: 0 done; 2 bad input or failed jobs (one line);\n"
               "  74 input/output error (disk full, read-only or unwritable path; one line naming it);\n"
               "  130 Ctrl-C, 143 SIGTERM (one line saying what was kept; nothing partial is presented as complete)")


class Terminated(KeyboardInterrupt):
    """Raised in the main thread by the SIGTERM handler that :func:`run_main` installs: a KeyboardInterrupt, so
    that every ``finally`` and ``except KeyboardInterrupt`` that cleans up after Ctrl-C does so after SIGTERM too."""


#: the signals received during the current :func:`run_main` call (an interrupt can surface as another error)
_signals_received: list[int] = []


#: how long a signal that arrived inside LLVM waits before it is delivered again [s]
REDELIVERY_SECONDS = 0.05


def _inside_llvm(frame) -> bool:
    """Whether ``frame`` (the one a signal interrupted) runs inside llvmlite, e.g. in one of the ctypes callbacks
    by which LLVM reports a kernel it compiled: an exception raised there is printed and dropped by ctypes."""
    llvmlite = sys.modules.get("llvmlite")
    locations = list(getattr(llvmlite, "__path__", None) or [])  # the package's folder, once it is imported
    if not locations:
        return False
    root = os.path.join(locations[0], "")
    while frame is not None:
        if frame.f_code.co_filename.startswith(root):
            return True
        frame = frame.f_back
    return False


def _deliver(signum, frame, exc_type: type[BaseException]) -> None:
    """Raise ``exc_type`` for the signal, or, inside LLVM (where the exception would be lost and the command would
    go on), send the signal again after :data:`REDELIVERY_SECONDS`, until it arrives outside."""
    if _inside_llvm(frame):
        timer = threading.Timer(REDELIVERY_SECONDS, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        return
    _signals_received.append(signum)
    raise exc_type()


def _raise_terminated(signum, frame):
    _deliver(signum, frame, Terminated)


def _raise_interrupt(signum, frame):
    _deliver(signum, frame, KeyboardInterrupt)


def interrupted(exc: BaseException, kept: str) -> BaseException:
    """Attach ``kept`` (what the interrupted command kept, how to continue) to a KeyboardInterrupt, for the
    one-line message of :func:`run_main`; returns ``exc`` (``raise interrupted(exc, "...")``)."""
    exc.kept = kept
    return exc


def io_error_message(exc: OSError) -> str:
    """One line for an OSError: the path(s), and what went wrong in words."""
    reason = {errno.ENOSPC: "no space left on the device (disk full)", errno.EROFS: "read-only file system",
              errno.EACCES: "permission denied", errno.EPERM: "operation not permitted",
              errno.ENOTDIR: "a path component is a file, not a directory",
              errno.EDQUOT: "disk quota exceeded"}.get(exc.errno, exc.strerror or str(exc))
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    where = " -> ".join(paths) if paths else "(no path given by the system)"
    return f"cannot write {where}: {reason}; files already written were replaced atomically and are whole"


def run_main(main, argv=None, prog: str | None = None) -> int:
    """``main(argv)`` with ConfigError -> one-line message and exit 2, OSError -> one line naming the path and exit
    74, Ctrl-C (KeyboardInterrupt) -> exit 130 and SIGTERM (:class:`Terminated`, from a handler installed for the
    call in the main thread) -> exit 143, each with one line saying what was kept (``exc.kept``, see
    :func:`interrupted`)."""
    name = prog or (sys.argv[0].rsplit("/", 1)[-1] if sys.argv and sys.argv[0] else "script")
    previous = {}
    _signals_received.clear()
    if threading.current_thread() is threading.main_thread():
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _raise_terminated)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # Python's own Ctrl-C handler only
            previous[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_interrupt)
    try:
        return main(argv)
    except ConfigError as exc:
        fail(name, str(exc))
    except KeyboardInterrupt as exc:
        fail(name, _interrupt_message(exc, isinstance(exc, Terminated)), code=_interrupt_code(exc))
    except OSError as exc:
        fail(name, io_error_message(exc), code=EXIT_IO_ERROR)
    except Exception as exc:
        # an interrupt that surfaced as another error on its way out (e.g. SIGTERM inside numba's compiler,
        # which then fails to cache the half-compiled kernel): still an interrupt, not a crash
        if not _signals_received:
            raise
        terminated = _signals_received[0] == signal.SIGTERM
        fail(name, _interrupt_message(exc, terminated), code=EXIT_SIGTERM if terminated else EXIT_SIGINT)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _interrupt_code(exc: KeyboardInterrupt) -> int:
    return EXIT_SIGTERM if isinstance(exc, Terminated) else EXIT_SIGINT


def _interrupt_message(exc: BaseException, terminated: bool) -> str:
    what = "terminated (SIGTERM)" if terminated else "interrupted (Ctrl-C)"
    kept = getattr(exc, "kept", None) or ("the run is incomplete and its result was not written; no file is left "
                                          "half-written (each is written atomically: the old one or a complete "
                                          "new one)")
    return f"{what}: {kept}"


# ------------------------------------------------------------------------- argparse value types
def int_arg(lo: int | None = None, hi: int | None = None):
    """An argparse type: a base-10 integer in [lo, hi] (errors name the bound)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if lo is not None and value < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo:,}, got {value:,}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"must be <= {hi:,}, got {value:,}")
        return value

    parse.__name__ = "integer"
    return parse


def float_arg(lo: float | None = None, hi: float | None = None, lo_open: bool = False):
    """An argparse type: a finite float in [lo, hi] ((lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            raise argparse.ArgumentTypeError(f"must be {'>' if lo_open else '>='} {lo:g}, got {value:g}")
        if hi is not None and value > hi:
            raise argparse.ArgumentTypeError(f"must be <= {hi:g}, got {value:g}")
        return value

    parse.__name__ = "number"
    return parse


def path_arg(text: str) -> Path:
    """An argparse type: a non-empty path (an empty string would be the current directory, which no one means)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {text!r}")
    return Path(text)


path_arg.__name__ = "path"


def refuse_repeated(parser: argparse.ArgumentParser, flag: str, items: list[str] | None, keyed: bool = True) -> None:
    """``parser.error`` if a repeatable option names the same key twice (``keyed``: items ``KEY=VALUE``, compared by
    KEY; else by the whole item): the second would silently replace or repeat the first."""
    seen: dict[str, str] = {}
    for item in items or []:
        key = item.partition("=")[0].strip() if keyed else item
        if key in seen:
            what = f"{flag} {key} is given twice ({seen[key]}, {item})" if keyed else f"{flag} {item} is given twice"
            parser.error(f"{what}; give it once")
        seen[key] = item


def check_output_file(path: Path, force: bool, option: str = "--json") -> None:
    """ConfigError unless ``path`` can be written as a file (checked before any work is done); an OSError naming
    ``path`` (exit 74) if the disk or the quota is full."""
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a directory; expected a file name")
    if path.exists() and not force:
        raise ConfigError(f"{option} {path} exists; pass --force to overwrite it (nothing was written)")
    parent = path.parent
    while not parent.exists() and parent.parent != parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{option} {path}: {parent} is a file, not a directory")
    _check_writable(parent, f"{option} {path}", path)


def check_output_dir(path: Path, option: str) -> None:
    """ConfigError unless ``path`` is, or can be created as, a writable directory: checked before any work, so
    that an output under /proc, under a file, or in a read-only place is refused at once (``os.access`` and
    the mount's read-only flag, which hold for root too); an OSError naming ``path`` (exit 74) on a full disk."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path} is a file; expected a directory")
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(f"{option} {path}: {probe} is a file, not a directory")
    _check_writable(probe, f"{option} {path}", path)


#: bytes written to the probe file: a full disk (or an exhausted quota) refuses them before any work
PROBE_BYTES = 4096
_FULL = (errno.ENOSPC, errno.EDQUOT)


def _check_writable(directory: Path, what: str, target: Path) -> None:
    """ConfigError unless files can be created in ``directory``; OSError naming ``target`` (exit 74) if the disk or
    the quota is full."""
    if not os.access(directory, os.W_OK | os.X_OK):
        raise ConfigError(f"{what}: directory {directory} is not writable")
    try:
        read_only = bool(os.statvfs(directory).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    if read_only:
        raise ConfigError(f"{what}: directory {directory} is on a read-only file system")
    try:  # /proc, /sys and the like pass both checks above: try to create a file, and to write to it
        fd, tmp = _probe_file(directory)
    except OSError as exc:
        if exc.errno in _FULL:
            raise OSError(exc.errno, exc.strerror, str(target)) from None
        raise ConfigError(f"{what}: cannot create files in {directory} ({exc.strerror or exc})") from None
    try:
        os.write(fd, b"\0" * PROBE_BYTES)
    except OSError as exc:
        if exc.errno in _FULL:
            raise OSError(exc.errno, exc.strerror, str(target)) from None
        raise ConfigError(f"{what}: cannot write files in {directory} ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
        os.unlink(tmp)


def _probe_file(directory: Path):
    return tempfile.mkstemp(prefix=".write-probe.", dir=directory)


def read_json_report(path: Path, what: str) -> dict:
    """A JSON object written by a command (``what`` names it in errors); ConfigError if unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no {what} at {path}")
    try:
        data = loads_json(path.read_text(encoding="utf-8"), str(path))  # bounded size and nesting
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(f"{what} {path} is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{what} {path} is not a JSON object")
    return data


def command_main(script: str, body, summary: str):
    """The ``main(argv=None, *, layout=None, prog=script) -> int`` of a subcommand, written once for all of them:
    the packages the command needs are checked first (:func:`~softpvtol_gym.baselines.util.extras.require`),
    then ``body(argv, layout, prog)`` runs with one-line errors (:func:`run_main`). ``layout``: where outputs
    go (default: the current directory's, :class:`~softpvtol_gym.baselines.util.paths.Layout`); ``prog``: the
    name in messages (``softpvtol SUB`` from the console command, the script's name from a checkout)."""

    def main(argv=None, *, layout: Layout | None = None, prog: str = script) -> int:
        require(script, prog=prog)
        return run_main(lambda args: body(args, layout or Layout(), prog), argv, prog=prog)

    main.__doc__ = summary
    return main


def refuse_overwrite(parser: argparse.ArgumentParser, args, content: tuple[str, ...], outputs) -> None:
    """ConfigError if a run with other settings than the defaults would overwrite an existing default output
    (in a checkout: a committed result) without ``--force``.

    ``content``: the destinations of the options that change what is computed; ``outputs``: (path, default
    path, option) of each file the run writes."""
    if getattr(args, "force", False):
        return
    def same(a, b) -> bool:
        return Path(a).resolve() == Path(b).resolve() if isinstance(a, Path) and isinstance(b, Path) else a == b

    changed = [f"--{name.replace('_', '-')}" for name in content
               if not same(getattr(args, name), parser.get_default(name))]
    if not changed:
        return
    for path, default, option in outputs:
        if path is not None and Path(path).exists() and Path(path).resolve() == Path(default).resolve():
            raise ConfigError(f"{', '.join(changed)} would overwrite {path}, the default run's output, with a "
                              f"different run; pass {option} for another file, or --force to overwrite it (nothing "
                              f"was written)")
