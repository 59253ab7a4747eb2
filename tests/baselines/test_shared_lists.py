"""The thin form of a JSON document: rebuilt byte for byte from the files whose lists it shares, or one error."""

from __future__ import annotations

import json

import pytest

from softpvtol_gym.baselines.util.shared_lists import REF_KEY, RebuildError, is_thin, thick, thin

EPISODES = [{"return": 1.0 / 3.0, "crashed": False}, {"return": 2.0 ** 0.5, "crashed": True}]
SOURCES = {"runs/a/eval.json": json.dumps({"eval": {"nominal": EPISODES}, "tiers": ["nominal"]}).encode()}
DOC = {"meta": {"tiers": ["nominal"]}, "cells": [{"entry": "a", "episodes": EPISODES, "selection": []},
                                                 {"entry": "b", "episodes": [{"return": 5.0, "crashed": False}]}]}
DATA = json.dumps(DOC, indent=1, allow_nan=False).encode()


def test_a_thin_document_refers_to_the_shared_lists_and_rebuilds_byte_for_byte():
    thinned = thin(DATA, SOURCES)
    assert is_thin(thinned) and not is_thin(DATA)
    document = json.loads(thinned)["document"]
    assert document["cells"][0]["episodes"] == {REF_KEY: ["runs/a/eval.json", "eval", "nominal"]}
    assert document["cells"][1]["episodes"] == DOC["cells"][1]["episodes"]  # in no source: kept inline
    assert document["meta"]["tiers"] == ["nominal"]  # lists of scalars are not shared
    assert thick(thinned, SOURCES.__getitem__) == DATA


@pytest.mark.parametrize("data", [b"not json", json.dumps(DOC).encode(),  # not written with indent=1
                                  json.dumps({"x": [{REF_KEY: 1}]}, indent=1).encode(), b"[1, 2]",
                                  json.dumps({"x": [{"a": float("nan")}]}, indent=1).encode()])
def test_a_document_that_would_not_rebuild_exactly_is_stored_whole(data):
    assert thin(data, SOURCES) is None


def test_a_source_that_changed_or_is_missing_is_named():
    thinned = thin(DATA, SOURCES)
    changed = {"runs/a/eval.json": SOURCES["runs/a/eval.json"].replace(b"true", b"false")}
    with pytest.raises(RebuildError, match="runs/a/eval.json is not the file it was made from"):
        thick(thinned, changed.__getitem__)
    with pytest.raises(RebuildError, match="runs/a/eval.json is missing"):
        thick(thinned, {}.__getitem__)


def test_a_source_with_nan_is_no_obstacle():
    sources = {**SOURCES, "runs/b/eval.json": b'{"eval": {"nominal": [{"return": NaN}]}}'}
    assert thick(thin(DATA, sources), sources.__getitem__) == DATA
