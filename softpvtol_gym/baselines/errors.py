"""The errors the baselines raise for things a user must fix (bad input, unusable files, a busy run).

The commands turn every one of them into exit code 2 and a one-line message
(:func:`softpvtol_gym.baselines.util.args.run_main`). This module imports nothing beyond the standard library,
so that a missing optional dependency can still be reported.
"""

from __future__ import annotations

#: the exit codes of every command (``--help`` lists them: :data:`~softpvtol_gym.baselines.util.args.EXIT_EPILOG`)
EXIT_OK, EXIT_BAD_INPUT, EXIT_IO_ERROR, EXIT_SIGINT, EXIT_SIGTERM = 0, 2, 74, 130, 143


class ConfigError(ValueError):
    """A bad configuration value or input: the message names what was received and what is expected."""


class CheckpointError(ConfigError):
    """A checkpoint that cannot be used: missing, incomplete, corrupt, or in a format that could run code."""


class LockedError(ConfigError):
    """A run directory or job root that another process is using (the message names it)."""
