"""Command-line plumbing shared by the scripts: one-line errors with exit code 2, never a traceback for
input a user can fix.

:class:`Parser` is an ``argparse.ArgumentParser`` whose errors are one line (``prog: error: ...``) and
exit 2; :func:`run_main` runs a script's ``main`` and turns a :class:`~baselines.errors.ConfigError`
(bad input, an unusable checkpoint, a busy run directory) into the same one-line exit 2, and Ctrl-C into
exit 130.
"""

from __future__ import annotations

import argparse
import math
import sys

from .errors import ConfigError


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
