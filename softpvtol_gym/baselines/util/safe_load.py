"""JSON and YAML parsing with bounds: size, nesting depth, node count (YAML aliases expanded).

Every file a command reads (checkpoint manifests and descriptions, config.yaml, hyperparameter files,
search spaces, leaderboard specs, eval.json, ...) goes through these two functions, so a crafted file
ends in one error naming the file instead of a ``RecursionError`` (nesting), a hang (a YAML "billion
laughs" alias bomb) or memory exhaustion (size):

* at most :data:`MAX_BYTES` bytes (64 MiB: the largest file the project writes, a replay buffer, is an
  npz and is not parsed here; JSON and YAML files are kilobytes);
* at most :data:`MAX_DEPTH` levels of nested lists / mappings (the deepest file the project writes has
  6);
* YAML: at most :data:`MAX_NODES` nodes and :data:`MAX_DEPTH` levels counted with every alias expanded
  (an alias bomb, aliases of aliases that expand to billions of nodes, is refused while it is read,
  without expanding it), only the safe loader's standard tags;
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
MAX_NODES = 100_000


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
    raise ValueError(f"{name}: non-finite numbers (NaN, Infinity) are not allowed here")


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
    """PyYAML's SafeLoader with the nesting depth and the node count bounded *as if every alias were expanded*
    (the project's hyperparameter files use anchors and aliases; an alias bomb nests aliases of aliases
    until the expanded document has billions of nodes). Checked while the document is composed, bottom up
    (each node's expanded size and height from its children's), so nothing is ever expanded."""

    max_depth = MAX_DEPTH
    max_nodes = MAX_NODES

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._size: dict[int, int] = {}    # id(node) -> nodes below it, aliases expanded (itself included)
        self._height: dict[int, int] = {}  # id(node) -> levels below it, aliases expanded (itself included)
        self._keep: list = []              # the nodes whose ids are recorded (ids stay unique)

    def _fail(self, problem: str, mark):
        raise yaml.composer.ComposerError(None, None, problem, mark)

    def compose_node(self, parent, index):
        mark = self.peek_event().start_mark
        alias = self.check_event(yaml.AliasEvent)
        self._depth += 1
        if self._depth > self.max_depth:
            self._fail(f"nested more than {self.max_depth} levels deep", mark)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if not alias:
            children = node.value if isinstance(node, yaml.SequenceNode) else (
                [n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode) else [])
            self._size[id(node)] = 1 + sum(self._size.get(id(c), 1) for c in children)
            self._height[id(node)] = 1 + max((self._height.get(id(c), 1) for c in children), default=0)
            self._keep.append(node)
        if self._size.get(id(node), 1) > self.max_nodes:
            self._fail(f"more than {self.max_nodes:,} nodes once its aliases are expanded", mark)
        if self._depth + self._height.get(id(node), 1) - 1 > self.max_depth:
            self._fail(f"nested more than {self.max_depth} levels deep" + (" once its aliases are expanded"
                                                                          if alias else ""), mark)
        return node


def loads_yaml(text: bytes | str, source: str, *, error=UnsafeInputError, max_bytes: int = MAX_BYTES,
               max_depth: int = MAX_DEPTH) -> Any:
    """``yaml.safe_load(text)`` within the bounds of the module docstring; ``error(message)`` otherwise
    (with the line and column of a syntax error)."""
    _check_size(text, source, max_bytes, error)
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise error(f"{source} is not UTF-8 text ({exc}); expected a YAML file") from None
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
