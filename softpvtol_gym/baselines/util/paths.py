"""Names that become paths: safe slugs, and paths that must stay under a root directory."""

from __future__ import annotations

import re
from pathlib import Path

from .errors import ConfigError

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
