"""mkdocs hook: the pages link into the repository as they do on GitHub, and the site follows those links.

The Markdown files are written to read well on GitHub, so a page in ``docs/`` links to a result image as
``../results/leaderboard.png`` and the README links to ``docs/env.md``. mkdocs only knows the
files under ``docs/``; this hook

* adds every repository file that a page links to outside ``docs/`` (the committed result images under
  ``results/`` and ``benchmarks/``, a JSON or YAML file) to the site at its repository path, so
  that nothing is copied into ``docs/`` and no large binary is duplicated in git;
* rewrites such links to point at that copy, and links to the repository's Markdown files that the site
  shows as pages (README.md, CHANGELOG.md, results/README.md, the benchmarks' reports) to those pages;
* fills the pages that show a repository file (``<!-- repo-file: PATH -->`` as their whole text) with that
  file, its links rewritten the same way.

A link to a file that does not exist is left alone, so ``mkdocs build --strict`` still fails on it.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
#: repository Markdown files that the site shows as pages: repository path -> page (under docs/)
PAGES = {"README.md": "index.md", "CHANGELOG.md": "changelog.md", "results/README.md": "results.md",
         "benchmarks/README.md": "dev/benchmarks.md", "benchmarks/RESULTS.md": "dev/benchmark-results.md",
         "benchmarks/TRACKING_EVALUATION.md": "dev/tracking-evaluation.md",
         "benchmarks/STUDIES.md": "dev/studies.md"}
INCLUDE = re.compile(r"^\s*<!-- repo-file: (\S+) -->\s*$")
# inline links and images: [text](target) / ![alt](target "title"); targets without spaces
LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)((?:\s+\"[^\"]*\")?\))")
FENCE = re.compile(r"^(```|~~~)")


def _is_relative(target: str) -> bool:
    return not (target.startswith(("#", "/", "mailto:")) or re.match(r"^[a-z][a-z0-9+.-]*://", target))


def _source(page_src: str) -> tuple[str, str]:
    """(text, repository directory of the text) of a page: its own file, or the repository file it shows."""
    text = (ROOT / "docs" / page_src).read_text(encoding="utf-8")
    m = INCLUDE.match(text)
    if m:
        path = m.group(1)
        return (ROOT / path).read_text(encoding="utf-8"), posixpath.dirname(path)
    return text, posixpath.dirname(posixpath.join("docs", page_src))


def _targets(text: str, base: str):
    """(match, repository path of the target) of each relative link outside code fences."""
    fenced = False
    for line in text.splitlines(keepends=True):
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in LINK.finditer(line):
            target = m.group(2)
            if _is_relative(target):
                path = target.split("#", 1)[0]
                if path:
                    yield m, posixpath.normpath(posixpath.join(base, path))


def _rewrite(text: str, base: str, page_src: str) -> str:
    """Links of ``text`` (written relative to the repository directory ``base``) made relative to the
    site page ``page_src`` (a path under docs/)."""
    page_dir = posixpath.dirname(page_src)
    out, fenced = [], False
    for line in text.splitlines(keepends=True):
        if FENCE.match(line.lstrip()):
            fenced = not fenced
        if not fenced:
            line = LINK.sub(lambda m: _link(m, base, page_dir), line)
        out.append(line)
    return "".join(out)


def _link(m: re.Match, base: str, page_dir: str) -> str:
    target = m.group(2)
    if not _is_relative(target):
        return m.group(0)
    path, _, anchor = target.partition("#")
    if not path:
        return m.group(0)
    repo_path = posixpath.normpath(posixpath.join(base, path))
    if repo_path in PAGES:
        site_path = PAGES[repo_path]
    elif repo_path.startswith("docs/"):
        site_path = repo_path[len("docs/"):]
    elif (ROOT / repo_path).is_file():
        site_path = repo_path  # added to the site by on_files
    else:
        return m.group(0)  # missing: left for mkdocs to report
    new = posixpath.relpath(site_path, page_dir or ".") + (f"#{anchor}" if anchor else "")
    return f"{m.group(1)}{new}{m.group(3)}"


def on_files(files, config):
    """Add the repository files (outside docs/) that the pages link to."""
    wanted = set()
    for f in files.documentation_pages():
        text, base = _source(f.src_uri)
        for _, repo_path in _targets(text, base):
            if (repo_path not in PAGES and not repo_path.startswith(("docs/", "..")) and (ROOT / repo_path).is_file()
                    and not repo_path.endswith(".md")):
                wanted.add(repo_path)
    for repo_path in sorted(wanted):
        if files.get_file_from_path(repo_path) is None:
            files.append(File(repo_path, str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown, page, config, files):
    """Fill ``<!-- repo-file: PATH -->`` pages, and rewrite repository links for the site."""
    m = INCLUDE.match(markdown)
    if m:
        path = m.group(1)
        return _rewrite((ROOT / path).read_text(encoding="utf-8"), posixpath.dirname(path), page.file.src_uri)
    return _rewrite(markdown, posixpath.dirname(posixpath.join("docs", page.file.src_uri)), page.file.src_uri)
