"""Every code block of the README and of docs/ runs as written.

* ```python blocks: each runs in a fresh interpreter (its own script file, cwd = the repository root,
  headless rendering). A block that cannot run here says why in an HTML comment on the line before it,
  ``<!-- docs-test: skip (reason) -->``; ``test_skipped_blocks_are_few_and_known`` lists them.
* ```bash blocks: every command that starts with ``softpvtol SUB``, ``python train.py`` or
  ``python baselines/X.py`` names a command that exists, and each ``--option`` it uses is one that the
  command's ``--help`` lists (the work itself is not run). pip, venv, pytest and other lines are not run.
* docs/env.md's Arguments table is the one ``softpvtol_gym.envs.config.argument_table_markdown()`` generates
  (``python -m tests.docs.test_code_blocks`` rewrites it).
"""

from __future__ import annotations

import functools
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SKIP = re.compile(r"^\s*<!-- docs-test: skip \((.+)\) -->\s*$")
FENCE = re.compile(r"^(\s*)```(\w*)\s*$")
#: the skipped blocks (file, reason prefix): a new skip must be added here on purpose
KNOWN_SKIPS = {
    ("docs/env.md", "needs the video extra"),
    ("docs/rllib.md", "needs ray[rllib]"),
}
ARGS_START = "<!-- argument_table_markdown: table start (generated from softpvtol_gym/envs/config.py, do not edit) -->"
ARGS_END = "<!-- argument_table_markdown: table end -->"


@dataclass(frozen=True)
class Block:
    path: str  # relative to the repository root
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    skip: str | None  # the reason, if marked

    @property
    def id(self) -> str:
        return f"{self.path}:{self.line}"


def code_blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a Markdown file (indented fences included, their indent removed)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m or not m.group(2):
            i += 1
            continue
        indent, lang, start = m.group(1), m.group(2), i
        body = []
        i += 1
        while i < len(lines) and lines[i].strip() != "```":
            body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i])
            i += 1
        prev = lines[start - 1] if start > 0 else ""
        skip = SKIP.match(prev)
        blocks.append(Block(path.relative_to(ROOT).as_posix(), start + 1, lang, "\n".join(body) + "\n",
                            skip.group(1) if skip else None))
        i += 1
    return blocks


ALL_BLOCKS = [b for f in DOC_FILES for b in code_blocks(f)]
PYTHON = [b for b in ALL_BLOCKS if b.lang == "python"]
BASH = [b for b in ALL_BLOCKS if b.lang == "bash"]


def test_the_docs_have_code_blocks():
    # the parser finds the blocks (a broken fence pattern would make every test below vacuous)
    assert len(PYTHON) >= 8 and len(BASH) >= 5
    assert any(b.path == "README.md" for b in PYTHON) and any(b.path == "README.md" for b in BASH)


def test_skipped_blocks_are_few_and_known():
    skipped = {(b.path, b.skip) for b in ALL_BLOCKS if b.skip}
    print("skipped blocks:", *sorted(f"{p}: {r}" for p, r in skipped), sep="\n  ")
    unknown = [(p, r) for p, r in skipped if not any(p == kp and r.startswith(kr) for kp, kr in KNOWN_SKIPS)]
    assert not unknown, f"new skipped blocks {unknown}: make them run, or add them to KNOWN_SKIPS on purpose"
    assert len(skipped) <= len(KNOWN_SKIPS)


def _runnable(block: Block):
    """A block as a test parameter; the Ray examples join the tests that start Ray, which run one at a time
    (each checks that no other Ray runs beside it)."""
    marks = [pytest.mark.xdist_group("ray")] if block.path == "docs/rllib.md" else []
    return pytest.param(block, marks=marks, id=block.id)


@pytest.mark.slow  # about 2.5 min in all on 2 cores (a fresh interpreter per block; a custom task compiles)
@pytest.mark.parametrize("block", [_runnable(b) for b in PYTHON if not b.skip])
def test_python_block_runs(block, tmp_path):
    script = tmp_path / "block.py"
    script.write_text(block.code)
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, str(script)], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"{block.id} failed:\n{block.code}\n--- stderr:\n{proc.stderr[-3000:]}"


# ------------------------------------------------------------------------------------ commands
def commands(code: str) -> list[list[str]]:
    """The simple commands of a bash block (split at &&, ||, ; and |; comments dropped; continuation lines
    joined), as argument lists."""
    code = code.replace("\\\n", " ")
    out = []
    for line in code.splitlines():
        try:
            words = shlex.split(line, comments=True)
        except ValueError as e:
            raise AssertionError(f"unparsable shell line {line!r}: {e}") from e
        cmd: list[str] = []
        for w in words + ["&&"]:
            if w in ("&&", "||", ";", "|"):
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return out


def program(cmd: list[str]) -> tuple[tuple[str, ...], list[str]] | None:
    """(the program to ask for --help, its arguments) for the commands this test checks, else None."""
    if cmd[0] == "softpvtol" and len(cmd) > 1:
        return ("softpvtol", cmd[1]), cmd[2:]
    if cmd[0] == "python" and len(cmd) > 1 and (cmd[1] == "train.py" or re.fullmatch(r"baselines/\w+\.py", cmd[1])):
        if cmd[1] == "baselines/export.py" and len(cmd) > 2 and not cmd[2].startswith("-"):
            return ("python", cmd[1], cmd[2]), cmd[3:]  # export's own subcommands
        return ("python", cmd[1]), cmd[2:]
    return None


def _softpvtol() -> str:
    exe = Path(sys.executable).parent / "softpvtol"
    assert exe.exists(), (f"{exe} not found: the softpvtol console command comes with the package's install "
                          "(pip install -e '.[baselines]')")
    return str(exe)


@functools.cache
def help_text(prog: tuple[str, ...]) -> str:
    argv = [_softpvtol(), *prog[1:]] if prog[0] == "softpvtol" else [sys.executable, *prog[1:]]
    proc = subprocess.run([*argv, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "SDL_VIDEODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"})
    assert proc.returncode == 0, f"{' '.join(prog)} --help exited {proc.returncode}:\n{proc.stderr[-2000:]}"
    return proc.stdout


CHECKED = [(b, cmd) for b in BASH if not b.skip for cmd in commands(b.code) if program(cmd)]


def test_bash_blocks_use_the_commands():
    assert any(program(c)[0][0] == "softpvtol" for _, c in CHECKED)
    assert any(program(c)[0][:2] == ("python", "train.py") for _, c in CHECKED)


@pytest.mark.parametrize("block, cmd", CHECKED, ids=[f"{b.id}:{' '.join(c[:3])}" for b, c in CHECKED])
def test_bash_command_exists_with_its_options(block, cmd):
    prog, args = program(cmd)
    text = help_text(prog)
    for a in args:
        if a.startswith("--"):
            option = a.split("=", 1)[0]
            assert re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text), \
                f"{block.id}: `{' '.join(cmd)}`: {option} is not an option of `{' '.join(prog)}`"


# ------------------------------------------------------------------------------- arguments table
def _argument_table() -> str:
    from softpvtol_gym.envs.config import argument_table_markdown

    return argument_table_markdown().strip()


def test_env_arguments_table_is_the_generated_one():
    text = (ROOT / "docs" / "env.md").read_text(encoding="utf-8")
    body = text[text.index(ARGS_START) + len(ARGS_START):text.index(ARGS_END)].strip()
    assert body == _argument_table(), (
        "docs/env.md's Arguments table is stale: run python -m tests.docs.test_code_blocks")


def write_argument_table(path: Path = ROOT / "docs" / "env.md") -> None:
    text = path.read_text(encoding="utf-8")
    a, b = text.index(ARGS_START) + len(ARGS_START), text.index(ARGS_END)
    path.write_text(text[:a] + "\n" + _argument_table() + "\n" + text[b:], encoding="utf-8")


if __name__ == "__main__":  # python -m tests.docs.test_code_blocks: rewrite docs/env.md's Arguments table
    sys.path.insert(0, str(ROOT))
    write_argument_table()
    print("rewrote the Arguments table of docs/env.md")


def test_docs_site_builds_strictly(tmp_path):
    """The mkdocs-material site (mkdocs.yml) builds with --strict: a broken link, a missing page or image, an
    unresolved API reference or a docstring warning fails (the test extra installs the docs extra)."""
    pytest.importorskip("mkdocs", reason="the docs extra (pip install -e '.[docs]') builds the site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "api" / "index.html").is_file()
