"""The README is a front door: short, and every link and picture in it leads somewhere;
the pages its measurement notes moved to link to files and headings that exist."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
#: the documentation site's pages (the toctree of docs/index.md names them)
PAGES = sorted((ROOT / "docs").glob("*.md"))


def links(text: str) -> list[str]:
    """The targets of the Markdown links and images of ``text`` outside code blocks,
    web addresses left out."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    return [t for t in targets if not re.match(r"[a-z]+://", t)]


def slug(heading: str) -> str:
    """The anchor of a heading, as MyST (myst_heading_anchors) and GitHub make it."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {slug(h) for h in re.findall(r"^#{1,3} (.*)$", text, re.M)}


def test_the_readme_reads_in_five_minutes():
    assert len(README.splitlines()) <= 150


def test_the_readme_has_one_short_python_example():
    """One example (tests/test_api.py runs it as printed), of about fifteen lines."""
    examples = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert len(examples) == 1
    assert len(examples[0].strip().splitlines()) <= 16


def test_every_relative_link_and_picture_of_the_readme_resolves():
    local = links(README)
    assert len(local) >= 20  # the table of contents and the picture
    assert any(re.search(r"\.png$", t) for t in local), "the README shows one picture"
    for target in local:
        path, _, anchor = target.partition("#")
        assert (ROOT / path).exists(), f"README links to {target}, which is not in the tree"
        if anchor and path.endswith(".md"):
            assert anchor in anchors(ROOT / path), f"README links to {target}: no such heading"


def test_every_page_the_readme_links_is_in_the_documentation_site():
    """A docs page the README points to is in the site's table of contents."""
    index = (ROOT / "docs" / "index.md").read_text()
    for page in re.findall(r"\]\(docs/([a-z_]+)\.md[)#]", README):
        assert re.search(rf"^{page}$", index, re.M), f"docs/{page}.md is not in docs/index.md"


def test_every_page_of_the_site_is_in_its_table_of_contents():
    index = (ROOT / "docs" / "index.md").read_text()
    for page in PAGES:
        if page.stem != "index":
            assert re.search(rf"^{page.stem}$", index, re.M), f"{page.name} is not in the toctree"


def test_every_relative_link_and_picture_of_the_pages_resolves():
    """Relative to docs/: a file, and for a page with an anchor, one of its headings."""
    checked = 0
    for page in PAGES:
        for target in links(page.read_text()):
            path, _, anchor = target.partition("#")
            where = page if not path else page.parent / path
            assert where.exists(), f"{page.name} links to {target}, which is not in the tree"
            if anchor and where.suffix == ".md":
                assert anchor in anchors(where), f"{page.name} links to {target}: no such heading"
            checked += 1
    assert checked >= 50
