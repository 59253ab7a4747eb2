"""Names that become paths: safe slugs, and paths that must stay under a root directory."""

from __future__ import annotations

import dataclasses
import importlib.resources
import re
from pathlib import Path

from softpvtol_gym.baselines.errors import ConfigError

#: a job or entry name: lower-case letters, digits, '.', '_', '-', starting with a letter or digit
SLUG_RE = re.compile(r"^[a-z0-9][a-z0-9._-]{0,99}$")


def check_slug(value, what: str) -> str:
    """``value`` if it is a safe slug (see :data:`SLUG_RE`), else ConfigError naming ``what``."""
    if not isinstance(value, str) or not SLUG_RE.match(value) or ".." in value:
        raise ConfigError(f"{what} must be a lower-case name of letters, digits, '.', '_' and '-' (no '..', at most "
                          f"100 characters), starting with a letter or digit; got {value!r}")
    return value


def under(root: Path, relative: str | Path, what: str = "path") -> Path:
    """``root / relative``, refusing anything that resolves outside ``root`` (``..``, absolute paths,
    symlinks out of it)."""
    root = Path(root)
    rel = Path(relative)
    if rel.is_absolute() or ".." in rel.parts:
        raise ConfigError(f"{what} {str(relative)!r} must be a relative path inside {root} without '..'")
    out = root / rel
    try:
        out.resolve().relative_to(root.resolve())
    except ValueError:
        raise ConfigError(f"{what} {str(relative)!r} resolves to {out.resolve()}, outside {root.resolve()}") from None
    return out


# ------------------------------------------------------------------------------- where outputs go
def data_file(*parts: str) -> Path:
    """A read-only file shipped with the package (``softpvtol_gym/baselines/data/...``): the hyperparameter
    YAML per env id, the leaderboard spec, the tuning space. Every command that reads one takes an option to
    pass another file."""
    return Path(str(importlib.resources.files("softpvtol_gym.baselines").joinpath("data", *parts)))


@dataclasses.dataclass(frozen=True)
class Layout:
    """Where the commands write by default, and which generated Markdown blocks they refresh.

    The console command (``softpvtol``) uses ``Layout()``: every output under the current directory
    (``./results/...``; training runs under ``./runs/``, as before), and no README or docs page is touched.
    A source checkout's scripts (``python baselines/<script>.py``, ``python train.py``) pass the checkout's
    layout (``results/``, the README and ``docs/`` blocks); the library never finds a checkout by
    itself.

    ``root``: paths recorded in result files (a checkpoint's path in a leaderboard job's ``eval.json``) are
    written relative to it where they lie under it; the git commit recorded with results is read there.
    ``readme`` / ``docs``: the README and the docs folder whose generated blocks
    (:mod:`softpvtol_gym.baselines.util.blocks`) a command refreshes when it wrote its default output;
    None: no block is refreshed.
    """

    results: Path = Path("results")
    root: Path = Path(".")
    readme: Path | None = None
    docs: Path | None = None

    @property
    def runs(self) -> Path:
        """The leaderboard jobs' run directories."""
        return self.results / "leaderboard_runs"

    def doc(self, name: str) -> Path | None:
        """A docs page (``docs/<name>``) of the layout, or None without a docs folder."""
        return None if self.docs is None else self.docs / name


def relative_to_root(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` where it lies under it, else as given."""
    try:
        return str(Path(path).resolve().relative_to(Path(root).resolve()))
    except ValueError:
        return str(path)
