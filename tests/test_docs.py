"""Every relative link and ``#anchor`` of the project's markdown documents resolves.

The documents are ``README.md``, ``writeup.md`` and ``docs/*.md``. Each markdown link or image
(``[text](target)``, ``![alt](target)``) and each HTML ``href``/``src`` outside code blocks and
code spans is checked: a relative file must exist inside the repository, and an ``#anchor`` (on
its own, or after a markdown file) must match a heading of the target as GitHub slugs it:
lowercased, punctuation dropped except hyphens and spaces (letters, digits and underscores stay),
spaces turned into hyphens, and ``-1``, ``-2``, ... appended to repeated headings.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from conftest import REPO

_FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.S)
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HTML = re.compile(r"""<(?:img|a|source|video)\b[^>]*?\b(?:src|href)\s*=\s*["']([^"']+)["']""", re.I)
_HEADING = re.compile(r"^ {0,3}(#{1,6})[ \t]+(.+?)[ \t#]*$", re.M)
_HTML_ANCHOR = re.compile(r"""<a\b[^>]*\b(?:name|id)\s*=\s*["']([^"']+)["']""", re.I)


def documents(repo: Path = REPO) -> list[Path]:
    docs = [repo / "README.md", repo / "writeup.md", *sorted((repo / "docs").glob("*.md"))]
    return [p for p in docs if p.is_file()]


def _prose(text: str) -> str:
    """The text without fenced code blocks and inline code spans (links there are code, not links)."""
    return _CODE_SPAN.sub("", _FENCE.sub("", text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading: its text
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor a markdown file offers: its headings' slugs (repeats numbered) and HTML anchors."""
    text = _FENCE.sub("", path.read_text(encoding="utf-8"))
    seen: dict[str, int] = {}
    out = set(_HTML_ANCHOR.findall(text))
    for _, heading in _HEADING.findall(text):
        base = slug(heading)
        n = seen.get(base, 0)
        out.add(base if n == 0 else f"{base}-{n}")
        seen[base] = n + 1
    return out


def links(path: Path) -> list[str]:
    text = _prose(path.read_text(encoding="utf-8"))
    return _LINK.findall(text) + _HTML.findall(text)


def _external(target: str) -> bool:
    return bool(re.match(r"^(?:[a-z][a-z0-9+.-]*:|//)", target, re.I))


def broken_links(path: Path, repo: Path = REPO) -> list[str]:
    """Each link of ``path`` whose file is missing or whose anchor no heading of its target gives."""
    broken = []
    for target in links(path):
        if _external(target):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path.resolve()
        if not dest.exists() or repo.resolve() not in (dest, *dest.parents):
            broken.append(f"{target} (no such file)")
            continue
        if anchor and dest.suffix.lower() == ".md" and anchor not in anchors(dest):
            broken.append(f"{target} (no heading '{anchor}' in {dest.relative_to(repo.resolve())})")
    return broken


def test_the_documents_are_there():
    names = {p.relative_to(REPO).as_posix() for p in documents()}
    assert {"README.md", "writeup.md", "docs/experiments.md"} <= names


@pytest.mark.parametrize("doc", documents(), ids=lambda p: p.relative_to(REPO).as_posix())
def test_links_resolve(doc):
    broken = broken_links(doc)
    assert not broken, f"{doc.relative_to(REPO)}: {len(broken)} broken link(s):\n" + "\n".join(broken)


def test_writeup_links_the_experiment_log():
    assert any(t.split("#", 1)[0] == "docs/experiments.md" for t in links(REPO / "writeup.md"))


@pytest.mark.parametrize(
    ("heading", "expected"),
    [
        ("3.4 Other cameras", "34-other-cameras"),
        ("Appendix: the README's Measured table with its history (until 2026-11-26)", "appendix-the-readmes-measured-table-with-its-history-until-2026-11-26"),
        ("Sides fitted to the frame: `refine.fit_sides`", "sides-fitted-to-the-frame-refinefit_sides"),
        ("Lanes on any dashcam", "lanes-on-any-dashcam"),
    ],
)
def test_slug_follows_github(heading, expected):
    assert slug(heading) == expected


def test_a_broken_link_fails(tmp_path):
    """The check can fail: a missing file, a missing anchor and a missing local anchor are reported."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "target.md").write_text("# Title\n\n## 2.3 Less work: two stages\n\n## Repeat\n\n## Repeat\n", encoding="utf-8")
    doc = tmp_path / "docs" / "doc.md"
    doc.write_text(
        "# Doc\n\n"
        "[ok](../target.md#23-less-work-two-stages) [ok](../target.md#repeat-1) [ok](#doc) [web](https://example.com/x#y)\n"
        "`[in code](missing.md)`\n\n```\n[in a block](missing.md)\n```\n"
        "[gone](../missing.md) [bad anchor](../target.md#24-less-work) [bad local](#nowhere)\n",
        encoding="utf-8",
    )
    broken = broken_links(doc, repo=tmp_path)
    assert [b.split(" ", 1)[0] for b in broken] == ["../missing.md", "../target.md#24-less-work", "#nowhere"]
