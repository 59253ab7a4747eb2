"""No tracked file names a path outside the repository: the project reads and cites only its own tree.

Every text file of the checkout (``git ls-files``; without git, every file but the ignored ones: a virtual
environment, caches, build output) is scanned, docs, code, tests, configuration and committed results alike:

* a relative path that climbs (a leading ``..`` component) must name something inside the repository: it is
  resolved from every directory of the tree (a doc links from ``docs/``, a renderer writes a link for a page in
  another folder) and at least one of those must stay inside the root and exist;
* no absolute path of a machine: what lies in a home, scratch or mount directory (``/home``, ``/root``,
  ``/Users``, ``/work``, ``/tmp``, ``/mnt``, ``/shared``, ``/scratch``) or in a Windows user folder.

A test that needs such a path as data (a path-traversal case) builds it (``tests.conftest.UP``, ``os.pardir``),
so that no file names one.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: a relative path that climbs: one or more ``../`` then a name
CLIMBING = re.compile(r"(?<![\w.~/-])(?:\.\./)+[\w.-]*(?:/[\w.-]+)*")
MACHINE = re.compile(r"(?<![\w.~:/-])/(?:home|root|Users|work|tmp|mnt|shared|scratch)/[^\s\"'`)\],;]*"
                     r"|\b[A-Za-z]:\\Users\\\S*")
#: what a checkout holds beside its tracked files when git is not there to ask
IGNORED_PARTS = {".git", ".venv", "__pycache__", ".pytest_cache", ".ruff_cache", ".hypothesis", "site", "build",
                 "dist", "runs", "logs"}


def tracked_files(root: Path = ROOT) -> list[Path]:
    """The repository's files: git's list where the checkout is a git repository, else every file that is not
    one of :data:`IGNORED_PARTS`' outputs."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
        names = [n for n in out.decode("utf-8", "surrogateescape").split("\0") if n]
        if names:
            return [root / n for n in names if (root / n).is_file()]
    except (OSError, subprocess.CalledProcessError):
        pass
    return [p for p in root.rglob("*") if p.is_file() and not IGNORED_PARTS & set(p.relative_to(root).parts)
            and not p.name.endswith(".egg-info")]


def read_text(path: Path) -> str | None:
    """The file's text, or None for a binary file (a NUL byte, or not UTF-8)."""
    data = path.read_bytes()
    if b"\0" in data:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def directories(files: list[Path], root: Path) -> list[Path]:
    """Every directory of the tree of ``files`` (each file's folder and the folders above it, up to the root)."""
    return sorted({d for f in files for d in f.parents if d == root or root in d.parents})


def outside_paths(text: str, here: Path, root: Path, dirs: list[Path]) -> list[str]:
    """The paths that ``text`` (a file in directory ``here``) names outside the repository at ``root``: absolute
    machine paths, and climbing relative paths that no directory of ``dirs`` (``here`` first) resolves to an
    existing path inside the root."""
    found = [m.group(0) for m in MACHINE.finditer(text)]
    root = root.resolve()
    for m in CLIMBING.finditer(text):
        word = m.group(0).rstrip(".")
        inside = False
        for d in [here, *dirs]:
            target = Path(os.path.normpath(d.resolve() / word))
            if (target == root or root in target.parents) and target.exists():
                inside = True
                break
        if not inside:
            found.append(word)
    return found


FILES = tracked_files()
DIRS = directories(FILES, ROOT)


@pytest.mark.parametrize("folder", sorted({f.relative_to(ROOT).parts[0] if len(f.relative_to(ROOT).parts) > 1
                                           else "." for f in FILES}))
def test_no_tracked_file_names_a_path_outside_the_repository(folder):
    bad = {}
    for f in FILES:
        rel = f.relative_to(ROOT)
        if (rel.parts[0] if len(rel.parts) > 1 else ".") != folder:
            continue
        text = read_text(f)
        if text is None:
            continue
        found = outside_paths(text, f.parent, ROOT, DIRS)
        if found:
            bad[str(rel)] = sorted(set(found))[:5]
    assert not bad, f"tracked files name paths outside the repository (cite them from inside it): {bad}"


def test_the_scan_covers_code_docs_tests_configuration_and_results():
    names = {str(f.relative_to(ROOT)) for f in FILES}
    for expected in ("README.md", "docs/model.md", "pyproject.toml", ".ci/run", "tests/conftest.py",
                     "softpvtol_gym/dynamics.py", "results/passivity_metrics.json"):
        assert expected in names


def test_the_checker_fails_on_planted_paths(tmp_path):
    up = os.pardir
    (tmp_path / "docs").mkdir()
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "chart.png").write_bytes(b"")
    files = [tmp_path / "README.md", tmp_path / "docs" / "page.md", tmp_path / "results" / "chart.png"]
    dirs = directories(files, tmp_path)
    planted = f"See {up}/elsewhere/file and [a chart]({up}/results/chart.png)."
    assert outside_paths(planted, tmp_path / "docs", tmp_path, dirs) == [f"{up}/elsewhere/file"]
    assert outside_paths(planted, tmp_path, tmp_path, dirs) == [f"{up}/elsewhere/file"]
    assert outside_paths(f"the paper in `{up}/{up}/paper/p.txt`", tmp_path / "docs", tmp_path, dirs) == [
        f"{up}/{up}/paper/p.txt"]
    machine = "/".join(["", "work", "checkout", "a.py"]) + " and " + "/".join(["", "tmp", "x.json"])
    assert outside_paths(machine, tmp_path, tmp_path, dirs) == ["/".join(["", "work", "checkout", "a.py"]),
                                                                "/".join(["", "tmp", "x.json"])]
    assert outside_paths("a URL https://example.org/home/x, ~/.cache/softpvtol-gym, results/chart.png",
                         tmp_path, tmp_path, dirs) == []


def test_a_planted_reference_in_a_real_file_fails():
    readme = ROOT / "README.md"
    text = readme.read_text(encoding="utf-8")
    assert outside_paths(text, ROOT, ROOT, DIRS) == []
    planted = text + f"\nThe paper: {os.pardir}/elsewhere/file\n"
    assert outside_paths(planted, ROOT, ROOT, DIRS) == [f"{os.pardir}/elsewhere/file"]
