"""The README's, the results index's and docs' relative links lead to files that exist and to headings that exist."""

import pathlib
import re

ROOT = pathlib.Path(__file__).parents[1]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def github_anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: pathlib.Path) -> set[str]:
    headings = [line.lstrip("#").strip() for line in path.read_text().splitlines() if re.match(r"#{1,6} ", line)]
    return {github_anchor(h) for h in headings}


def test_github_anchor_matches_githubs_rule():
    assert github_anchor("Training on the authors' task") == "training-on-the-authors-task"
    assert github_anchor("Measured stiffness and motion (`match_jax.envs.probes.static_compliance`, tests)") == \
        "measured-stiffness-and-motion-match_jaxenvsprobesstatic_compliance-tests"


def test_relative_links_and_anchors_resolve():
    pages = [ROOT / "README.md", ROOT / "results" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        for target in LINK.findall(page.read_text()):
            if re.match(r"[a-z]+:", target):  # http(s), mailto
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, "\n".join(broken)
