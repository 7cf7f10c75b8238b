#!/usr/bin/env python3
"""Checks the README, the changelog and the book (docs/) for what a reader trips on.

- every relative link names a file that exists, and every `#anchor` a heading of that file (the
  slugs GitHub and mdBook make: lower case, spaces to hyphens, punctuation dropped);
- the book's pages link only inside docs/ (mdBook renders docs/ alone: a file of the repository is
  named in code, not linked), and every page of docs/ is in docs/SUMMARY.md;
- the README and the book name no past issue ("issue 12"): what changed lives in CHANGELOG.md.

Prints every problem as FILE:LINE: what, and exits 1 if there is any. Usage:
scripts/check-docs.py [REPO]
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

LINK = re.compile(r"(?<!\!)\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
ISSUE = re.compile(r"\bissues? \d+\b", re.IGNORECASE)


def slug(text: str) -> str:
    text = re.sub(r"`([^`]*)`", r"\1", text)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def prose_lines(text: str):
    """(line number, line) outside fenced code blocks and indented ones (four spaces after a
    blank line, and the lines that follow them)."""
    fenced = False
    code = False
    blank = True
    for number, line in enumerate(text.split("\n"), start=1):
        if line.startswith("```"):
            fenced = not fenced
            blank = False
            continue
        if line.strip() == "":
            blank = True
            continue
        code = line.startswith("    ") and (blank or code)
        blank = False
        if not fenced and not code:
            yield number, line


def anchors(path: Path) -> set[str]:
    found: set[str] = set()
    seen: dict[str, int] = {}
    for _, line in prose_lines(path.read_text()):
        match = HEADING.match(line)
        if match:
            base = slug(match[2])
            count = seen.get(base, 0)
            seen[base] = count + 1
            found.add(base if count == 0 else f"{base}-{count}")
    return found


def check(repo: Path) -> list[str]:
    docs = repo / "docs"
    pages = sorted(docs.glob("*.md"))
    files = [repo / "README.md", repo / "CHANGELOG.md", *pages]
    problems: list[str] = []
    cache: dict[Path, set[str]] = {}
    for path in files:
        shown = path.relative_to(repo)
        in_book = path.parent == docs
        for number, line in prose_lines(path.read_text()):
            if path.name != "CHANGELOG.md" and path.name != "design.md" and ISSUE.search(line):
                problems.append(f"{shown}:{number}: names a past issue "
                                f"({ISSUE.search(line)[0]!r}): say what is, not when it came")
            for match in LINK.finditer(line):
                target = match[1] or match[2]
                if re.match(r"[a-z]+:", target):
                    continue
                file_part, _, anchor = target.partition("#")
                destination = (path.parent / file_part).resolve() if file_part else path
                if file_part and not destination.exists():
                    problems.append(f"{shown}:{number}: link to {target}: no such file")
                    continue
                if in_book and file_part and not destination.is_relative_to(docs.resolve()):
                    problems.append(f"{shown}:{number}: link to {target} leaves docs/: the book "
                                    "is rendered alone; name the file in code instead")
                if anchor and destination.suffix == ".md":
                    names = cache.setdefault(destination, anchors(destination))
                    if anchor not in names:
                        near = sorted(n for n in names if anchor[:6] in n)[:3]
                        hint = f" (did you mean {', '.join('#' + n for n in near)}?)" if near else ""
                        problems.append(f"{shown}:{number}: link to {target}: no heading "
                                        f"#{anchor} in {destination.name}{hint}")
    summary = (docs / "SUMMARY.md").read_text()
    listed = set(re.findall(r"\]\(([^)#]+)\)", summary))
    for page in pages:
        if page.name != "SUMMARY.md" and page.name not in listed:
            problems.append(f"docs/{page.name}: not in docs/SUMMARY.md, so not in the book")
    return problems


def main() -> int:
    repo = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent)
    problems = check(repo)
    for problem in problems:
        print(problem)
    if problems:
        print(f"check-docs: {len(problems)} problem(s)", file=sys.stderr)
        return 1
    pages = len(list((repo / "docs").glob("*.md")))
    print(f"check-docs: README.md, CHANGELOG.md and {pages} pages of docs/: links and anchors resolve")
    return 0


if __name__ == "__main__":
    sys.exit(main())
