"""A JSON document stored without the lists that other JSON files already hold, and rebuilt from them exactly.

The leaderboard JSON repeats every job's per-episode metrics, which the jobs' ``eval.json`` hold already. Its
archive keeps a *thin* form: each list of objects in the document that equals a list in one of the ``sources``
(a mapping of name -> JSON bytes, e.g. ``"leaderboard_runs/<job>/seed_0/eval.json"``) is replaced by a reference
``{REF_KEY: [name, key, key, ...]}`` (the keys that lead to the list in that source). :func:`thick` puts the lists
back and checks each source and the result against the sha256 recorded of them, so a rebuilt file is the
original, byte for byte, or an error that names the source that is not the one it was thinned against.

:func:`thin` returns None where the document cannot be rebuilt exactly (not JSON, not written as
``json.dumps(doc, indent=1)``, or holding the reference key itself): the caller stores it whole.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable

#: the thin form's marker (its top-level key) and the key of a reference to a source's list
FORMAT_KEY, REF_KEY = "softpvtol-gym thin JSON", "$list"
FORMAT_VERSION = 1


class RebuildError(ValueError):
    """A thin document whose sources are missing or differ from those it was thinned against."""


def _dump(doc) -> bytes:
    return json.dumps(doc, indent=1, allow_nan=False).encode("utf-8")


def _lists(node, path: tuple, out: dict) -> None:
    """Index every list of records under ``node``: its key (:func:`_key`) -> the keys that lead to it (first found)."""
    if isinstance(node, dict):
        for key, value in node.items():
            _lists(value, (*path, key), out)
    elif _is_record_list(node):
        out.setdefault(_key(node), path)


def _key(node) -> str:
    """A list's index key: its compact JSON (NaN allowed: a source's list with NaN matches no document's, which
    :func:`thin` has checked to be finite)."""
    return json.dumps(node)


def _is_record_list(node) -> bool:
    """A non-empty list of objects (e.g. per-episode records): what is shared; short lists of scalars are not."""
    return isinstance(node, list) and bool(node) and all(isinstance(v, dict) for v in node)


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _refs(node):
    """Every reference (its [name, key, ...]) in a thin document."""
    if isinstance(node, dict):
        if set(node) == {REF_KEY}:
            yield node[REF_KEY]
        else:
            for v in node.values():
                yield from _refs(v)
    elif isinstance(node, list):
        for v in node:
            yield from _refs(v)


def _has_key(node, key: str) -> bool:
    if isinstance(node, dict):
        return key in node or any(_has_key(v, key) for v in node.values())
    if isinstance(node, list):
        return any(_has_key(v, key) for v in node)
    return False


def thin(data: bytes, sources: dict[str, bytes]) -> bytes | None:
    """The thin form of the JSON ``data`` against ``sources`` (name -> JSON bytes); None where ``data`` would not
    be rebuilt byte for byte (then store it whole). Sources that are not JSON objects are left out."""
    try:
        doc = json.loads(data)
        if not isinstance(doc, dict) or _dump(doc) != data or _has_key(doc, REF_KEY) or FORMAT_KEY in doc:
            return None
    except ValueError:  # not JSON, or holding NaN or infinity (never written with allow_nan=False)
        return None
    index: dict[str, tuple] = {}
    for name in sorted(sources):
        try:
            source = json.loads(sources[name])
        except ValueError:
            continue
        if isinstance(source, dict):
            _lists(source, (name,), index)

    def replace(node):
        if isinstance(node, dict):
            return {k: replace(v) for k, v in node.items()}
        if isinstance(node, list):
            ref = index.get(_key(node)) if _is_record_list(node) else None
            return {REF_KEY: list(ref)} if ref is not None else [replace(v) for v in node]
        return node

    document = replace(doc)
    used = sorted({ref[0] for ref in _refs(document)})
    out = {FORMAT_KEY: FORMAT_VERSION, "sha256": _sha256(data),
           "sources": {name: _sha256(sources[name]) for name in used}, "document": document}
    encoded = json.dumps(out, separators=(",", ":"), allow_nan=False).encode("utf-8")
    return encoded if thick(encoded, lambda name: sources[name]) == data else None


def is_thin(data: bytes) -> bool:
    """Whether ``data`` is a thin form written by :func:`thin`."""
    if not data.startswith(b'{"' + FORMAT_KEY.encode()):
        return False
    try:
        doc = json.loads(data)
    except ValueError:
        return False
    return isinstance(doc, dict) and doc.get(FORMAT_KEY) == FORMAT_VERSION


def thick(data: bytes, read: Callable[[str], bytes]) -> bytes:
    """The document that the thin form ``data`` was made of, its lists read from the sources (``read``: name ->
    bytes; OSError or KeyError for a missing one); RebuildError naming the source that is missing or differs."""
    wrapper = json.loads(data)
    parsed: dict[str, object] = {}

    expected = wrapper["sources"]

    def source(name: str):
        if name not in parsed:
            try:
                data = read(name)
            except (OSError, KeyError):
                raise RebuildError(f"{name} is missing") from None
            if _sha256(data) != expected.get(name):
                raise RebuildError(f"{name} is not the file it was made from")
            parsed[name] = json.loads(data)
        return parsed[name]

    def resolve(node):
        if isinstance(node, dict):
            if set(node) == {REF_KEY}:
                name, *keys = node[REF_KEY]
                value = source(name)
                for key in keys:
                    if not isinstance(value, dict) or key not in value:
                        raise RebuildError(f"{name} has no {'/'.join(keys)}")
                    value = value[key]
                return value
            return {k: resolve(v) for k, v in node.items()}
        if isinstance(node, list):
            return [resolve(v) for v in node]
        return node

    out = _dump(resolve(wrapper["document"]))
    if _sha256(out) != wrapper["sha256"]:
        raise RebuildError("the rebuilt document is not the one it was made from")
    return out
