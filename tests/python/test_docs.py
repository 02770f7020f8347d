# SPDX-License-Identifier: GPL-3.0-or-later
"""The README and the manual under docs/ hold together: every link and
picture resolves (the file exists; an anchor names a heading of that
page, as GitHub makes anchors), every page is reachable from the README and
every picture in docs/ is shown somewhere."""
import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOCS = os.path.join(ROOT, "docs")
PAGES = [os.path.join(ROOT, "README.md")] + sorted(
    os.path.join(DOCS, f) for f in os.listdir(DOCS) if f.endswith(".md"))
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def prose(path):
    """The page without its fenced code blocks and inline code."""
    text = re.sub(r"^```.*?^```", "", open(path, encoding="utf-8").read(), flags=re.M | re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def anchors(path):
    """GitHub's anchors for the headings of a page."""
    found = set()
    text = re.sub(r"^```.*?^```", "", open(path, encoding="utf-8").read(), flags=re.M | re.S)
    for heading in re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        base, n = slug, 1
        while slug in found:
            slug, n = "%s-%d" % (base, n), n + 1
        found.add(slug)
    return found


def links(path):
    return [t for t in LINK.findall(prose(path)) if not re.match(r"[a-z]+:", t)]


@pytest.mark.parametrize("page", PAGES, ids=[os.path.relpath(p, ROOT) for p in PAGES])
def test_every_link_and_picture_resolves(page):
    broken = []
    for target in links(page):
        file, _, anchor = target.partition("#")
        resolved = os.path.normpath(os.path.join(os.path.dirname(page), file)) if file else page
        if not os.path.exists(resolved):
            broken.append("%s: no such file" % target)
        elif anchor and resolved.endswith(".md") and anchor not in anchors(resolved):
            broken.append("%s: no heading for #%s" % (target, anchor))
    assert not broken, broken


def test_every_page_is_reachable_from_the_readme():
    seen, todo = set(), [PAGES[0]]
    while todo:
        page = todo.pop()
        if page in seen:
            continue
        seen.add(page)
        for target in links(page):
            file = target.partition("#")[0]
            resolved = os.path.normpath(os.path.join(os.path.dirname(page), file)) if file else page
            if resolved.endswith(".md") and os.path.exists(resolved):
                todo.append(resolved)
    assert sorted(set(PAGES) - seen) == []


def test_every_picture_in_docs_is_shown():
    shown = {os.path.normpath(os.path.join(os.path.dirname(p), t.partition("#")[0]))
             for p in PAGES for t in links(p)}
    pictures = {os.path.join(DOCS, f) for f in os.listdir(DOCS) if f.endswith((".png", ".jpg", ".svg"))}
    assert sorted(pictures - shown) == []


def test_the_checks_catch_a_broken_link(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n\n## A section\n\n[ok](#a-section) [bad](#missing) ![p](nothing.png) "
                    "`[code](ignored.md)`\n")
    assert anchors(str(page)) == {"title", "a-section"}
    assert links(str(page)) == ["#a-section", "#missing", "nothing.png"]
