"""The docs a user reads name no commit and no machine: those stay in the CHANGELOG and in the benchmarks' JSON.

Scanned: README.md, every Markdown file under docs/ and results/, and benchmarks/*.md (the scripts' README and the
reports they generate). A commit is a hexadecimal word of 7 to 40 characters with a digit and a letter (``2ee87ad``);
a machine is a CPU vendor's model name (``AMD EPYC``, ``Xeon``).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted({ROOT / "README.md", *(ROOT / "docs").rglob("*.md"), *(ROOT / "results").rglob("*.md"),
                *(ROOT / "benchmarks").glob("*.md")})
HEX_WORD = re.compile(r"(?<![\w./#-])[0-9a-f]{7,40}(?![\w-])")
CPU_MODEL = re.compile(r"\b(?:EPYC|Xeon|Ryzen|Threadripper|Opteron|Core\(TM\)|Intel\(R\)|AMX-capable|Graviton)\b", re.I)


def commits(text: str) -> list[str]:
    """The words of ``text`` that read as commit hashes."""
    return [w for w in HEX_WORD.findall(text) if re.search(r"\d", w) and re.search(r"[a-f]", w)]


def machines(text: str) -> list[str]:
    """The CPU model names in ``text``."""
    return CPU_MODEL.findall(text)


def test_the_scan_sees_commits_and_machines():
    assert commits("at commit 2ee87ad, then `4f8c2a1b`; full 2ee87ad143cb960f7d9b160960f6d383cefce887") == [
        "2ee87ad", "4f8c2a1b", "2ee87ad143cb960f7d9b160960f6d383cefce887"]
    assert commits("1e-10 rad, 1,000,000 seeds, deadbeef, 0.0186 m, sha256 of x.json, #a1b2c3d4") == []
    assert machines("on the AMD EPYC machine, an AMX-capable Xeon") == ["EPYC", "AMX-capable", "Xeon"]
    assert machines("2 cores, x86_64, numba's cores") == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_user_docs_name_no_commit_and_no_machine(page):
    text = page.read_text(encoding="utf-8")
    assert PAGES, "no pages scanned"
    found = commits(text) + machines(text)
    assert not found, (f"{page.relative_to(ROOT)} names {found[:5]}: commits and machines belong in CHANGELOG.md or "
                       "in the benchmark's JSON")
