"""The user-facing text names no path of a development machine and cites no file that does not exist.

Scanned: README.md, every Markdown file under docs/ and results/, benchmarks/README.md (but not CHANGELOG.md, a
record of what was, nor the reports the benchmark scripts generate), mkdocs.yml, the package's YAML data
(softpvtol_gym/**/*.yml) and the docstrings and comments of the package's modules (softpvtol_gym/**/*.py).

* No absolute machine path: a home or scratch directory (``/home``, ``/root``, ``/Users``, ``/work``,
  ``/tmp`` and what lies under them) or a virtual environment's files (``.venv/lib/...``; the set-up commands'
  ``. .venv/bin/activate`` in a clone is not one).
* Every repository file a text cites exists in the checkout: a link's target (relative to the file), and every
  path-like word in backticks or in the plain text that starts at a top-level folder of the repository
  (``baselines/x.py``, ``tests/docs/test_y.py``, ``results/leaderboard.json``) or that names a file by its
  extension (``control/kernels.py``: also looked up in the package, where the docs cite modules by their
  package path). Patterns (``*``), placeholders (``<...>``, ``{...}``, ``$VAR``) and ``~`` paths are not files.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

from tests.conftest import UP

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "softpvtol_gym"
#: top-level folders of the repository: a word starting with one of them is a repository path
TOP = ("baselines", "benchmarks", "docs", "results", "tests", PACKAGE, ".ci")
#: extensions of the files a text may cite
EXTENSIONS = ("py", "md", "json", "yml", "yaml", "toml", "png", "gif", "cff", "txt", "csv", "npz", "zip", "sh",
              "safetensors")

MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:home|root|Users|work|tmp)/\S*|(?<![\w-])\.venv/(?!bin/activate\b)\S*")
BACKTICKS = re.compile(r"(`+)([^`]+?)\1")
FENCED = re.compile(r"^[ \t]*```[^\n]*\n(.*?)^[ \t]*```[ \t]*$", re.S | re.M)
#: options whose value is a file a command writes, not one it cites
OUTPUT_OPTIONS = ("--out", "--json", "--markdown", "--chart", "--plot", "--page", "--gif-out", "--tracking-out",
                  "--curves-out", "-o")
OUTPUT_BEFORE = re.compile(r"(?:^|\s)(?:" + "|".join(OUTPUT_OPTIONS) + r")[ =]$")
LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
WORD = re.compile(r"(?<![\w/.-])(?:\.{1,2}/)*[\w.-]+(?:/[\w.-]+)+/?")
EXT = re.compile(r"\.(" + "|".join(EXTENSIONS) + r")$")
TOP_WORD = re.compile(r"(?<![\w/.-])(?:" + "|".join(re.escape(t) for t in TOP) + r")/[\w./-]*[\w/]")


def _is_placeholder(word: str) -> bool:
    return any(c in word for c in "*<>{}$~") or "..." in word


def cited_paths(text: str) -> list[str]:
    """The repository paths a text cites: link targets, path-like words in backticks and code blocks (but a
    file a command writes: the value of an output option such as ``--out``), and words in the plain text that
    start at a top-level folder. (Paths as written; :func:`missing_paths` resolves them.)"""
    out = []
    code = [m.group(1) for m in FENCED.finditer(text)]
    text = FENCED.sub("", text)
    code += [m.group(2) for m in BACKTICKS.finditer(text)]
    for m in LINK.finditer(text):
        target = m.group(1)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
            continue  # a URL, an anchor of the same page, an absolute site path
        out.append(target.split("#", 1)[0])
    for span in code:
        words = span.split()
        for i, word in enumerate(words):
            if i and words[i - 1] in OUTPUT_OPTIONS or word.startswith(tuple(o + "=" for o in OUTPUT_OPTIONS)):
                continue  # a file the command writes
            word = word.strip("\"'(),;:")
            word = word.split("=", 1)[1] if word.startswith("--") and "=" in word else word
            if word.startswith(("http", "--")) or not WORD.fullmatch(word):
                continue
            if word.startswith(tuple(t + "/" for t in TOP)) or EXT.search(word.rstrip("/")):
                out.append(word)
    plain = LINK.sub("", BACKTICKS.sub("", text))
    for m in TOP_WORD.finditer(plain):
        word = m.group(0).rstrip(".")
        if OUTPUT_BEFORE.search(plain[:m.start()]):
            continue  # a file the command writes
        if EXT.search(word) or word.endswith("/"):
            out.append(word)
    return [p for p in out if p and not _is_placeholder(p)]


def missing_paths(text: str, base: Path, root: Path = ROOT) -> list[str]:
    """The cited paths of ``text`` (a file in the folder ``base``) that exist neither relative to ``base`` nor to
    the repository root (nor, for a path within the package such as ``envs/config.py``, within the commands'
    data folder such as ``hyperparams/ppo.yml`` or within ``results/`` such as ``tracking/track_paper.png``,
    there)."""
    missing = []
    for path in cited_paths(text):
        clean = path.rstrip("/")
        candidates = [base / clean, root / clean, root / PACKAGE / clean, root / PACKAGE / "baselines" / "data" / clean,
                      root / "results" / clean]
        if not any(c.exists() for c in candidates):
            missing.append(path)
    return sorted(set(missing))


def machine_paths(text: str) -> list[str]:
    return sorted({m.group(0) for m in MACHINE_PATH.finditer(text)})


def python_prose(source: str) -> str:
    """The docstrings and comments of a Python module (the text a reader takes as documentation)."""
    parts = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                parts.append(doc)
    parts += [t.string for t in tokenize.generate_tokens(io.StringIO(source).readline) if t.type == tokenize.COMMENT]
    return "\n".join(parts)


def user_texts() -> list[tuple[Path, str]]:
    """(file, the text of it that a user reads) of every scanned file."""
    files = [ROOT / "README.md", ROOT / "mkdocs.yml", *sorted((ROOT / "docs").rglob("*.md")),
             *sorted((ROOT / "results").rglob("*.md")), ROOT / "benchmarks" / "README.md",
             *sorted((ROOT / PACKAGE).rglob("*.yml"))]
    texts = [(f, f.read_text(encoding="utf-8")) for f in files if f.is_file()]
    texts += [(f, python_prose(f.read_text(encoding="utf-8"))) for f in sorted((ROOT / PACKAGE).rglob("*.py"))]
    return texts


TEXTS = user_texts()


def _id(item: tuple[Path, str]) -> str:
    return item[0].relative_to(ROOT).as_posix()


def test_the_scan_covers_the_user_texts():
    names = {_id(t) for t in TEXTS}
    assert {"README.md", "mkdocs.yml", "docs/getting-started.md", "results/README.md", "benchmarks/README.md"} <= names
    assert "CHANGELOG.md" not in names
    assert any(n.endswith(".yml") and n.startswith(PACKAGE) for n in names)
    assert sum(n.endswith(".py") for n in names) > 20


@pytest.mark.parametrize("item", TEXTS, ids=_id)
def test_no_machine_path(item):
    path, text = item
    found = machine_paths(text)
    assert not found, f"{_id(item)} names paths of a machine: {found}"


@pytest.mark.parametrize("item", TEXTS, ids=_id)
def test_cited_files_exist(item):
    path, text = item
    missing = missing_paths(text, path.parent)
    assert not missing, f"{_id(item)} cites files that do not exist: {missing}"


# ------------------------------------------------------------------------------- the checker itself
def _abs(*parts: str) -> str:
    """An absolute path built from its parts, so that no file of the project names one."""
    return "/" + "/".join(parts)


def test_checker_finds_machine_paths():
    text = (f"Run `python {_abs('work', 'x', 'train.py')}`, logs in {_abs('home', 'ana', 'runs')} and "
            f"{_abs('tmp', 'scratch', 'a.json')},\n"
            f"then `. .venv/bin/activate`, from .venv/lib/python3.11/site-packages; {_abs('root', '.cache')} too.")
    assert machine_paths(text) == [".venv/lib/python3.11/site-packages;", _abs("home", "ana", "runs"),
                                   _abs("root", ".cache"), _abs("tmp", "scratch", "a.json,"),
                                   _abs("work", "x", "train.py`,")]
    assert machine_paths("the cache in `~/.cache/softpvtol-gym`, under $XDG_CACHE_HOME; a URL http://x/work/y") == []


def test_checker_finds_missing_cited_files(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "baselines").mkdir()
    (tmp_path / "baselines" / "evaluate.py").write_text("")
    (tmp_path / PACKAGE / "envs").mkdir(parents=True)
    (tmp_path / PACKAGE / "envs" / "config.py").write_text("")
    (tmp_path / "docs" / "env.md").write_text("")
    text = ("`python baselines/evaluate.py --spec results/gone.json --out results/new.json`, `baselines/missing.py`;\n"
            f"[the env](env.md), [gone]({UP}/results/old.png), module `envs/config.py`, `envs/old.py`;\n"
            "see tests/docs/test_nothing.py. Patterns: `results/leaderboard_runs/*/seed_*/`, `<checkout>/a.py`,\n"
            "a URL [x](https://example.org/a.md), an anchor [y](#z), a command `softpvtol evaluate --policy runs/s0`,\n"
            "a ``python\nbaselines/gone.py`` over two lines, and a block:\n\n```bash\npython baselines/old.py\n```\n"
            "    softpvtol evaluate --json results/written.json (an indented command)\n")
    assert missing_paths(text, tmp_path / "docs", root=tmp_path) == [
        f"{UP}/results/old.png", "baselines/gone.py", "baselines/missing.py", "baselines/old.py", "envs/old.py",
        "results/gone.json", "tests/docs/test_nothing.py"]


def test_checker_fails_on_a_planted_path_in_a_real_page():
    path, text = next(t for t in TEXTS if _id(t) == "README.md")
    assert not missing_paths(text, path.parent) and not machine_paths(text)
    planted = text + f"\nSee `baselines/results/leaderboard.json` and {_abs('work', 'checkout', 'README.md')}.\n"
    assert missing_paths(planted, path.parent) == ["baselines/results/leaderboard.json"]
    assert machine_paths(planted) == [_abs("work", "checkout", "README.md.")]


def test_python_prose_is_docstrings_and_comments():
    source = '"""Module: `a/b.py`."""\nX = "tests/not_prose.py"  # see docs/c.md\n\n\ndef f():\n    """`d/e.py`"""\n'
    prose = python_prose(source)
    assert "a/b.py" in prose and "docs/c.md" in prose and "d/e.py" in prose and "not_prose" not in prose
