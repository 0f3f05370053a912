"""Every relative link in README.md and docs/*.md points at a file that exists and, for a link into a Markdown file,
at a heading that file has (GitHub's anchors: lower case, punctuation dropped, spaces as hyphens, repeats numbered)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^(#{1,6}) (.+)$")
FENCE = re.compile(r"^\s*(```|~~~)")


def heading_anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading's text, e.g. "Two ground truths (2026-11-26)" -> "two-ground-truths-2026-11-26"."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors_of(markdown: str) -> set[str]:
    """The anchors of every heading outside code fences; a repeated anchor gets -1, -2, ... as on GitHub."""
    seen: dict[str, int] = {}
    anchors: set[str] = set()
    in_fence = False
    for line in markdown.split("\n"):
        if FENCE.match(line):
            in_fence = not in_fence
            continue
        match = None if in_fence else HEADING.match(line)
        if match:
            anchor = heading_anchor(match.group(2))
            count = seen.get(anchor, 0)
            seen[anchor] = count + 1
            anchors.add(anchor if count == 0 else f"{anchor}-{count}")
    return anchors


def broken_links(files: list[Path]) -> list[str]:
    """'FILE: TARGET (why)' for each relative link of `files` whose file or heading does not exist."""
    problems = []
    for source in files:
        for target in LINK.findall(source.read_text(encoding="utf-8")):
            if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
                continue
            path, _, fragment = target.partition("#")
            resolved = (source.parent / path).resolve() if path else source.resolve()
            if not resolved.exists():
                problems.append(f"{source.name}: {target} (no such file)")
            elif fragment and resolved.suffix == ".md" and fragment not in anchors_of(resolved.read_text(encoding="utf-8")):
                problems.append(f"{source.name}: {target} (no such heading)")
    return problems


def test_github_anchors_of_headings_with_punctuation_and_repeats():
    markdown = "# The README's table (as of 2026-11-28)\n## Rows\n```\n# not a heading\n```\n## Rows\n### Über `x`\n"
    assert anchors_of(markdown) == {"the-readmes-table-as-of-2026-11-28", "rows", "rows-1", "über-x"}


def test_a_link_to_a_missing_heading_or_file_is_reported(tmp_path):
    (tmp_path / "a.md").write_text("# Here\n[ok](#here) [ok](b.md#there) [bad](#nowhere) [bad](b.md#here) [bad](c.md)\n")
    (tmp_path / "b.md").write_text("## There\n[ok](https://example.org/#x)\n")
    assert broken_links([tmp_path / "a.md", tmp_path / "b.md"]) == [
        "a.md: #nowhere (no such heading)", "a.md: b.md#here (no such heading)", "a.md: c.md (no such file)"]


def test_every_link_in_the_readme_and_docs_resolves():
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    assert broken_links(files) == []
