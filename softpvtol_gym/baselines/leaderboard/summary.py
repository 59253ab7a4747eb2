"""The leaderboard's summary that ships inside the package: what ranking a policy needs (``meta`` and every
entry's ``aggregates`` row), without the per-run cells and episodes, so that ``softpvtol score`` ranks against the
committed entries wherever the package is installed.

``softpvtol leaderboard`` writes it beside the committed page (:func:`summary_bytes`); a test checks that it
equals the aggregates of ``results/leaderboard.json``.
"""

from __future__ import annotations

import json

from softpvtol_gym.baselines.util.paths import data_file

#: the packaged summary (package data of ``softpvtol_gym.baselines``)
SUMMARY_FILE = data_file("leaderboard_summary.json")


def summary_of(data: dict) -> dict:
    """A leaderboard JSON's summary: its ``meta`` and ``aggregates``, ``cells`` empty (a leaderboard JSON that
    :func:`~.stats.validate_data` accepts and :func:`~.score.rank` ranks against)."""
    return {"meta": data["meta"], "aggregates": data["aggregates"], "cells": []}


def summary_bytes(data: dict) -> bytes:
    """The summary file's content: one compact JSON line per aggregate row (small, and a diff shows the rows that
    changed)."""
    summary = summary_of(data)
    rows = ",\n".join(json.dumps(r, separators=(",", ":"), allow_nan=False) for r in summary["aggregates"])
    meta = json.dumps(summary["meta"], separators=(",", ":"), allow_nan=False)
    return f'{{"meta":{meta},\n"aggregates":[\n{rows}\n],\n"cells":[]}}\n'.encode()
