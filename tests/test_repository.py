"""The repository itself: a short README, documentation whose links and section
citations resolve, and no local paths or notes about how the work was organised.

Every check reads the files git tracks (``git ls-files`` at the repository root),
so untracked build output and virtual environments are never scanned.
"""
from __future__ import annotations

import re
import subprocess
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_MAX_LINES = 250

# Spelled in pieces so that this file does not match its own patterns.
_ORGANISATION = [
    r"\.\./" + "shared",
    r"\bsession" + r"\s+\d",
    r"\bthis" + r"\s+session",
    r"\bthe" + r"\s+issue\s+notes",
    r"\bbeyond" + r"\s+the\s+brief",
    r"\bthe" + r"\s+brief\b",
    r"\bthe" + r"\s+lead\b",
]
_LOCAL_PATH = re.compile(r"(?<![\w.-])/(?:" + "tmp" + "|" + "work" + "|" + "root" + r")/")
_CITATION = re.compile(r"docs/([A-Za-z0-9_-]+\.md)\s*((?:§\s*\d+(?:\.\d+)*(?:\s*(?:,|and|–|-|…|\.\.\.)\s*)?)+)")
_DOC_CITATION = re.compile(r"\[([A-Za-z0-9_-]+\.md)\s+((?:§\s*\d+(?:\.\d+)*(?:\s*(?:,|and|–|-|…)\s*)?)+)\]\(([^)#]*)")
_SECTION = re.compile(r"§\s*(\d+(?:\.\d+)*)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HTML_SRC = re.compile(r"""<(?:img|a)\b[^>]*\b(?:src|href)\s*=\s*["']([^"']+)["']""", re.IGNORECASE)


@lru_cache(maxsize=1)
def tracked() -> tuple[str, ...]:
    r = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    assert r.returncode == 0, f"git ls-files failed in {ROOT}: {r.stderr.decode(errors='replace')}"
    files = tuple(f for f in r.stdout.decode().split("\0") if f)
    assert "README.md" in files and "pyproject.toml" in files, "not the skelslice repository"
    return files


def _text(rel: str) -> str | None:
    """The file's text, or None for a binary file (or one deleted in the work tree)."""
    try:
        data = (ROOT / rel).read_bytes()
    except FileNotFoundError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _prose(text: str):
    """(line number, line) of a markdown text outside fenced code blocks."""
    fence = None
    for n, line in enumerate(text.splitlines(), 1):
        m = re.match(r"^\s*(```+|~~~+)", line)
        if m:
            if fence is None:
                fence = m.group(1)[0]
            elif m.group(1)[0] == fence:
                fence = None
            continue
        if fence is None:
            yield n, line


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    h = re.sub(r"<[^>]+>", "", heading).strip().lower()
    h = re.sub(r"[^\w\- ]", "", h)
    return h.replace(" ", "-")


@lru_cache(maxsize=None)
def _headings(rel: str) -> tuple[frozenset, frozenset]:
    """(section numbers, anchors) of a markdown file."""
    numbers, anchors, seen = set(), set(), {}
    for _, line in _prose((ROOT / rel).read_text(encoding="utf-8")):
        m = _HEADING.match(line)
        if not m:
            continue
        title = m.group(2)
        num = re.match(r"(\d+(?:\.\d+)*)\.?(?:\s|$)", title)
        if num:
            numbers.add(num.group(1))
        a = _slug(title)
        k = seen.get(a, 0)
        anchors.add(a if k == 0 else f"{a}-{k}")
        seen[a] = k + 1
    return frozenset(numbers), frozenset(anchors)


def _markdown_files() -> list[str]:
    return [f for f in tracked() if f == "README.md" or (f.startswith("docs/") and f.endswith(".md"))]


# --------------------------------------------------------------------------- (a)
def test_readme_is_short():
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= README_MAX_LINES, (f"README.md has {n} lines (at most {README_MAX_LINES}); "
                                   "move reference material into docs/")


# --------------------------------------------------------------------------- (b)
def test_no_notes_about_how_the_work_was_organised():
    pattern = re.compile("|".join(_ORGANISATION), re.IGNORECASE)
    hits = []
    for rel in tracked():
        text = _text(rel)
        if text is None:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            m = pattern.search(line)
            if m:
                hits.append(f"{rel}:{n}: {m.group(0)!r} in {line.strip()[:120]!r}")
    assert not hits, "the repository speaks of the product only:\n" + "\n".join(hits)


def test_benchmark_results_hold_no_local_paths():
    results = [f for f in tracked() if f.startswith("benchmarks/results/")]
    assert results, "benchmarks/results/ holds no tracked results"
    hits = []
    for rel in results:
        text = _text(rel) or ""
        for n, line in enumerate(text.splitlines(), 1):
            m = _LOCAL_PATH.search(line)
            if m:
                hits.append(f"{rel}:{n}: {line.strip()[:120]!r}")
    assert not hits, "benchmark results must not hold local paths:\n" + "\n".join(hits)


def test_benchmark_results_record_command_and_machine():
    import json

    for rel in (f for f in tracked() if f.startswith("benchmarks/results/")):
        text = _text(rel) or ""
        if rel.endswith(".json"):
            doc = json.loads(text)
            assert isinstance(doc.get("command"), str) and doc["command"].startswith(("python", "skelslice")), rel
            m = doc.get("machine")
            assert isinstance(m, dict), f"{rel}: no machine description"
            for key in ("cpu", "cores", "os", "python", "numba"):
                assert m.get(key), f"{rel}: the machine description lacks {key!r}"
        elif rel.endswith(".txt"):
            first, second = text.splitlines()[:2]
            assert first.startswith("command: python") and second.startswith("machine: "), rel


# --------------------------------------------------------------------------- (c)
def _citations():
    """(where, cited file, section numbers) of every ``docs/X.md §n`` in tracked text files,
    and of every ``[X.md §n](X.md)`` link in the documentation."""
    out = []
    for rel in tracked():
        text = _text(rel)
        if text is None:
            continue
        flat = re.sub(r"\s*\n\s*(#\s*)?", " ", text)       # a citation may wrap (comments too)
        for m in _CITATION.finditer(flat):
            out.append((rel, f"docs/{m.group(1)}", _SECTION.findall(m.group(2)), m.group(0)))
        if rel.endswith(".md"):
            base = (ROOT / rel).parent
            for m in _DOC_CITATION.finditer(flat):
                target = m.group(3).strip() or m.group(1)
                cited = (base / target).resolve().relative_to(ROOT).as_posix()
                assert Path(target).name == m.group(1), f"{rel}: {m.group(0)!r} links another file"
                out.append((rel, cited, _SECTION.findall(m.group(2)), m.group(0)))
    return out


def test_citations_point_at_existing_sections():
    cites = _citations()
    files = set(tracked())
    assert any(c[1] == "docs/math.md" for c in cites) and any(c[1] == "docs/formats.md" for c in cites)
    bad = []
    for where, cited, sections, text in cites:
        if cited not in files:
            bad.append(f"{where}: {text!r}: {cited} is not in the repository")
            continue
        numbers, _ = _headings(cited)
        for s in sections:
            if s not in numbers:
                bad.append(f"{where}: {text!r}: {cited} has no section {s}")
    assert not bad, "\n".join(bad)


def test_bare_citations_name_the_docs_folder():
    """In code, a section of a document is cited with the document's folder:
    ``docs/`` + the file name + the section sign and number, never the bare file name."""
    bare = re.compile(r"(?<![/\w\[])(?:[A-Za-z0-9_-]+)\.md\s+§|(?<![/\w])(?:math|formats)\.md\s+\d")
    hits = []
    for rel in tracked():
        if rel.endswith(".md"):
            continue
        text = _text(rel)
        for n, line in enumerate((text or "").splitlines(), 1):
            if bare.search(line):
                hits.append(f"{rel}:{n}: {line.strip()[:120]!r}")
    assert not hits, "\n".join(hits)


def test_sections_cited_inside_a_document_exist():
    """math.md and formats.md refer to their own sections as a bare section sign and number."""
    own = re.compile(r"(?<!EG22 )(?<!EG22's )(?<![\w.])§\s*(\d+(?:\.\d+)*)")
    bad = []
    for rel in ("docs/math.md", "docs/formats.md"):
        numbers, _ = _headings(rel)
        for n, line in _prose((ROOT / rel).read_text(encoding="utf-8")):
            line = re.sub(r"\[[^\]]*\.md[^\]]*\]\([^)]*\)", "", line)   # citations of other files
            line = re.sub(r"docs/\w+\.md\s*§[\d.]+", "", line)
            for s in own.findall(line):
                if s not in numbers:
                    bad.append(f"{rel}:{n}: §{s} is not a section of {rel}")
    assert not bad, "\n".join(bad)


# --------------------------------------------------------------------------- (d)
def _links(rel: str):
    for n, line in _prose((ROOT / rel).read_text(encoding="utf-8")):
        line = re.sub(r"`[^`]*`", "", line)              # inline code is not a link
        for m in list(_LINK.finditer(line)) + list(_HTML_SRC.finditer(line)):
            yield n, m.group(1)


def test_relative_links_resolve():
    files = set(tracked())
    bad = []
    checked = 0
    for rel in _markdown_files():
        base = (ROOT / rel).parent
        for n, target in _links(rel):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):      # http:, mailto: ...
                continue
            path, _, anchor = target.partition("#")
            dest = (base / path).resolve() if path else (ROOT / rel).resolve()
            try:
                dest_rel = dest.relative_to(ROOT).as_posix()
            except ValueError:
                bad.append(f"{rel}:{n}: {target} leaves the repository")
                continue
            checked += 1
            if dest_rel not in files and not any(f.startswith(dest_rel + "/") for f in files):
                bad.append(f"{rel}:{n}: {target} -> {dest_rel} is not in the repository")
            elif anchor and dest_rel.endswith(".md") and anchor not in _headings(dest_rel)[1]:
                bad.append(f"{rel}:{n}: {target}: {dest_rel} has no heading #{anchor}")
    assert checked > 50, checked
    assert not bad, "\n".join(bad)


def test_docs_index_lists_every_document():
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    listed = {t.partition("#")[0] for _, t in _links("docs/index.md")}
    missing = [f for f in _markdown_files() if f.startswith("docs/") and f != "docs/index.md"
               and Path(f).name not in listed]
    assert not missing, f"docs/index.md does not list {missing}"
    assert index.strip()


@pytest.mark.parametrize("needle", ["docs/math.md", "docs/formats.md"])
def test_the_cited_documents_are_tracked(needle):
    assert needle in tracked()
