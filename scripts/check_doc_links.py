"""Check that every relative link in README.md and docs/**/*.md points to an existing file.

    python scripts/check_doc_links.py [ROOT]

Markdown links and images (``[text](path)``, ``![alt](path)``) outside fenced code blocks;
web addresses (``http:``, ``https:``, ``mailto:``) and pure anchors (``#...``) are skipped,
an anchor after a path is ignored. Prints each broken link as ``file:line: target`` and exits
with status 1 if there is one.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def links(path: Path):
    """(line number, target) of every link in a markdown file, outside fenced code."""
    in_code = False
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            in_code = not in_code
            continue
        if not in_code:
            for m in LINK.finditer(line):
                yield n, m.group(1)


def broken(root: Path) -> list[str]:
    files = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    bad = []
    for md in files:
        for n, target in links(md):
            if target.startswith(("http:", "https:", "mailto:", "#")):
                continue
            if not (md.parent / target.split("#", 1)[0]).exists():
                bad.append(f"{md.relative_to(root)}:{n}: {target}")
    return bad


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else Path(__file__).resolve().parent.parent
    bad = broken(root)
    sys.stdout.write("".join(line + "\n" for line in bad))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
