"""The README is a front door: short, and every link and picture in it leads somewhere."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_readme_reads_in_five_minutes():
    assert len(README.splitlines()) <= 150


def test_every_relative_link_and_picture_of_the_readme_resolves():
    targets = re.findall(r"\]\(([^)\s]+)\)", README)
    local = [t for t in targets if not re.match(r"[a-z]+://", t)]
    assert len(local) >= 20  # the table of contents and the picture
    for target in local:
        path = target.split("#")[0]
        assert (ROOT / path).exists(), f"README links to {target}, which is not in the tree"


def test_every_page_the_readme_links_is_in_the_documentation_site():
    """A docs page the README points to is in the site's table of contents."""
    index = (ROOT / "docs" / "index.md").read_text()
    for page in re.findall(r"\]\(docs/([a-z_]+)\.md\)", README):
        assert re.search(rf"^{page}$", index, re.M), f"docs/{page}.md is not in docs/index.md"
