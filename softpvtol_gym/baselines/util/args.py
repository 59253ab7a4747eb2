"""Command-line plumbing shared by the subcommands: one-line errors with exit code 2, never a traceback for
input a user can fix.

:class:`Parser` is an ``argparse.ArgumentParser`` whose errors are one line (``prog: error: ...``) and exit 2;
:func:`run_main` runs a command's body and turns a :class:`~softpvtol_gym.baselines.errors.ConfigError` (bad
input, an unusable checkpoint, a busy run directory) into the same one-line exit 2, and Ctrl-C into exit 130;
:func:`command_main` makes a subcommand's ``main`` of its body (once, for all of them). Also the argparse value
types, the output-file check made before any work, and reading a command's JSON report.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from softpvtol_gym.baselines.errors import ConfigError
from softpvtol_gym.baselines.util.extras import require
from softpvtol_gym.baselines.util.paths import Layout


def one_line(message: str) -> str:
    return " ".join(str(message).split())


def fail(prog: str, message: str, code: int = 2):
    sys.stderr.write(f"{prog}: error: {one_line(message)}\n")
    sys.stderr.flush()
    raise SystemExit(code)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``prog: error: message (see prog --help)``), exit code 2."""

    def error(self, message: str):  # noqa: D401 (argparse API)
        fail(self.prog, f"{message} (see {self.prog} --help)")


def run_main(main, argv=None, prog: str | None = None) -> int:
    """``main(argv)`` with ConfigError -> one-line message and exit 2, KeyboardInterrupt -> exit 130."""
    name = prog or (sys.argv[0].rsplit("/", 1)[-1] if sys.argv and sys.argv[0] else "script")
    try:
        return main(argv)
    except ConfigError as exc:
        fail(name, str(exc))
    except KeyboardInterrupt:
        fail(name, "interrupted", code=130)


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


def check_output_file(path: Path, force: bool, option: str = "--json") -> None:
    """ConfigError unless ``path`` can be written as a file (checked before any work is done)."""
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a directory; expected a file name")
    if path.exists() and not force:
        raise ConfigError(f"{option} {path} exists; pass --force to overwrite it (nothing was written)")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{option} {path}: {parent} is a file, not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {path}: directory {parent} is not writable")


def read_json_report(path: Path, what: str) -> dict:
    """A JSON object written by a command (``what`` names it in errors); ConfigError if unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no {what} at {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
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
