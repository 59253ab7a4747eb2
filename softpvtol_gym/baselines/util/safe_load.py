"""JSON and YAML parsing with bounds: size, nesting depth, node count, no YAML aliases.

Every file a command reads (checkpoint manifests and descriptions, config.yaml, hyperparameter files,
search spaces, leaderboard specs, eval.json, ...) goes through these two functions, so a crafted file
ends in one error naming the file instead of a ``RecursionError`` (nesting), a hang (a YAML "billion
laughs" alias bomb) or memory exhaustion (size):

* at most :data:`MAX_BYTES` bytes (64 MiB: the largest file the project writes, a replay buffer, is an
  npz and is not parsed here; JSON and YAML files are kilobytes);
* at most :data:`MAX_DEPTH` levels of nested lists / mappings (the deepest file the project writes has
  6);
* YAML: no aliases (``*name``; the project never writes them, and they are what makes an alias bomb
  expand exponentially), at most :data:`MAX_NODES` nodes, only the safe loader's standard tags;
* JSON: ``NaN`` / ``Infinity`` refused unless ``allow_nan`` (the checkpoint files never hold them).

Failures raise ``error`` (a :class:`ValueError` subclass given by the caller, default
:class:`UnsafeInputError`) with a one-line message that starts with ``source``.
"""

from __future__ import annotations

import json
from typing import Any

import yaml

MAX_BYTES = 64 * 2**20
MAX_DEPTH = 64
MAX_NODES = 1_000_000


class UnsafeInputError(ValueError):
    """A JSON / YAML file that is too large, too deep, malformed or uses a refused construct."""


def nesting_depth(value: Any, limit: int = MAX_DEPTH) -> int:
    """Depth of nested lists / tuples / dicts in ``value`` (a scalar: 0), computed without recursion; stops
    counting once it exceeds ``limit`` (returns ``limit + 1``)."""
    deepest = 0
    stack = [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (list, tuple, dict)):
            d += 1
            if d > limit:
                return limit + 1
            deepest = max(deepest, d)
            stack.extend((x, d) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def _check_size(data, source: str, max_bytes: int, error) -> None:
    if len(data) > max_bytes:
        raise error(f"{source} is {len(data):,} bytes, more than the {max_bytes:,} this loader reads")


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a finite number (NaN and Infinity are not allowed here)")


def loads_json(data: bytes | str, source: str, *, error=UnsafeInputError, allow_nan: bool = True,
               max_bytes: int = MAX_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(data)`` within the bounds of the module docstring; ``error(message)`` otherwise."""
    _check_size(data, source, max_bytes, error)
    try:
        value = json.loads(data, parse_constant=None if allow_nan else _refuse_constant)
    except RecursionError:
        raise error(f"{source} is nested too deeply (more than {max_depth} levels)") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise error(f"{source} is not valid JSON ({exc})") from None
    if nesting_depth(value, max_depth) > max_depth:
        raise error(f"{source} is nested too deeply (more than {max_depth} levels)")
    return value


class _BoundedSafeLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader with aliases refused and the nesting depth and node count bounded (checked while
    the document is composed, before anything is constructed)."""

    max_depth = MAX_DEPTH
    max_nodes = MAX_NODES

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, f"alias *{event.anchor} (aliases are not allowed here)",
                                              event.start_mark)
        self._nodes += 1
        if self._nodes > self.max_nodes:
            raise yaml.composer.ComposerError(None, None, f"more than {self.max_nodes:,} nodes",
                                              self.peek_event().start_mark)
        self._depth += 1
        try:
            if self._depth > self.max_depth:
                raise yaml.composer.ComposerError(None, None, f"nested more than {self.max_depth} levels deep",
                                                  self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def loads_yaml(text: bytes | str, source: str, *, error=UnsafeInputError, max_bytes: int = MAX_BYTES,
               max_depth: int = MAX_DEPTH) -> Any:
    """``yaml.safe_load(text)`` within the bounds of the module docstring; ``error(message)`` otherwise
    (with the line and column of a syntax error)."""
    _check_size(text, source, max_bytes, error)
    loader = _BoundedSafeLoader(text)
    loader.max_depth = max_depth
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).replace("\n", " ")
        raise error(f"{source} is not valid YAML{where}: {problem}") from None
    except RecursionError:
        raise error(f"{source} is nested too deeply (more than {max_depth} levels)") from None
    finally:
        loader.dispose()
