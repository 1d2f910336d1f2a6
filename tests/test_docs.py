"""The documentation's links lead somewhere: every ``docs/...`` path the README and the code name, and every
relative link of a docs page, is a file of the repository (``make docs`` checks the rest: anchors,
cross-references, the API reference)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
# Written by `make docs`, not kept in git: named in prose, never linked.
GENERATED = ("docs/_build", "docs/api/_generated")

DOCS_PATH = re.compile(r"(?<![\w/.-])docs/[\w./-]*[\w/]")
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(`{3,}|~{3,})\s*(\S*)")
# MyST directives whose body is Markdown (glossary, note, toctree...) are read; code and reST are not.
NOT_MARKDOWN = {"", "{code-block}", "{code}", "{sourcecode}", "{eval-rst}", "{literalinclude}"}


def docs_paths(text: str) -> set[str]:
    """``docs/...`` paths named anywhere in ``text`` (links, code spans, prose)."""
    return {m.group(0).rstrip("/.") for m in DOCS_PATH.finditer(text)}


def markdown_links(text: str) -> list[str]:
    """Targets of ``[text](target)`` links, outside code blocks (a MyST directive's Markdown body counts)."""
    links: list[str] = []
    fences: list[tuple[str, bool]] = []  # open fences: (marker, is code)
    for line in text.splitlines():
        m = FENCE.match(line.lstrip())
        if m:
            marker, info = m.groups()
            if fences and marker.startswith(fences[-1][0][0]) and len(marker) >= len(fences[-1][0]) and not info:
                fences.pop()
                continue
            if not (fences and fences[-1][1]):
                fences.append((marker, not info.startswith("{") or info in NOT_MARKDOWN))
                continue
        if not (fences and fences[-1][1]):
            links += LINK.findall(line)
    return links


def missing(paths: set[str]) -> list[str]:
    return sorted(p for p in paths if not p.startswith(GENERATED) and not (ROOT / p).exists())


def test_the_readme_names_only_docs_files_that_exist():
    paths = docs_paths((ROOT / "README.md").read_text())
    assert "docs/formats/capture-format.md" in paths  # the check sees the README's links
    assert missing(paths) == []


def test_readme_is_short_and_links_resolve():
    """The README is the landing page (what hilbench is, the two commands, the tour, links): 400 lines at
    most, and every relative link it makes (to a docs page, to the data's README) is a file that exists."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 400
    links = [t.split("#", 1)[0] for t in markdown_links(text) if not re.match(r"[a-z][a-z0-9+.-]*:", t)]
    docs_links = [t for t in links if t.startswith("docs/")]
    assert "docs/start/two-commands.md" in docs_links and "docs/extending/tutorial.md" in docs_links
    assert sorted(t for t in links if t and not (ROOT / t).exists()) == []
    # the two commands stay on the landing page
    assert "make demo    #" in text and "make test    #" in text


def test_the_code_names_only_docs_files_that_exist():
    paths: set[str] = set()
    for path in [*ROOT.glob("hilbench/**/*.py"), *ROOT.glob("profiles/**/*.toml"), *ROOT.glob("tools/*.py")]:
        paths |= docs_paths(path.read_text())
    assert paths, "no docs/ path named in the code: the pattern is broken"
    assert missing(paths) == []


PAGES = sorted(p for p in DOCS.rglob("*.md") if "_build" not in p.parts and "_generated" not in p.parts)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_a_docs_page_links_only_to_files_that_exist(page: Path):
    text = page.read_text()
    broken = []
    for target in markdown_links(text):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL, or an anchor of this page (Sphinx checks anchors)
        path = target.split("#", 1)[0]
        if not (page.parent / path).exists():
            broken.append(target)
    assert broken == []
    assert missing(docs_paths(text)) == []


def test_the_pages_are_found():
    names = {str(p.relative_to(DOCS)) for p in PAGES}
    assert {"index.md", "glossary.md", "api/index.md", "families/index.md",
            "formats/capture-format.md", "formats/tracestamp-binary.md"} <= names


def test_a_broken_link_is_caught(tmp_path: Path):
    page = tmp_path / "page.md"
    page.write_text("[gone](nowhere.md#x) and [ok](page.md)\n```\n[in code](ignored.md)\n```\n"
                    "```{note}\n[in a note](gone-too.md)\n```\n")
    assert [t for t in markdown_links(page.read_text()) if not (tmp_path / t.split("#")[0]).exists()] == \
        ["nowhere.md#x", "gone-too.md"]
    assert missing(docs_paths("see docs/no-such-page.md.")) == ["docs/no-such-page.md"]
