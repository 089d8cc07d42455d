"""The command blocks of the project's documents, as a reader would copy them.

Every fenced ``bash`` block of README.md, docs/*.md and models/README.md is a block
of commands, run in the order the document gives them. A block that cannot run in
CI says so in the document, on the line before its fence::

    <!-- docs-test: skip: needs two hosts -->

and the test lists it as skipped with that reason. Nothing else is read from the
documents: the commands are never copied into the tests.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = ("README.md", "docs/*.md", "models/README.md")
FENCE = re.compile(r"^```(\w*)\s*$")
SKIP = re.compile(r"^<!--\s*docs-test:\s*skip:\s*(?P<reason>.+?)\s*-->\s*$")
SHELLS = ("bash", "sh", "shell")


@dataclass(frozen=True)
class Block:
    """One fenced shell block: where it is, its text, and why it is not run (None: it is run)."""

    document: str
    line: int
    text: str
    skip: str | None = None

    @property
    def name(self) -> str:
        return f"{self.document}:{self.line}"

    def first_command(self) -> str:
        for line in self.text.splitlines():
            if line.strip() and not line.lstrip().startswith("#"):
                return line.strip()
        return ""


def documents(root: Path = ROOT) -> list[Path]:
    """The documents whose commands are tested, in a fixed order."""
    found: list[Path] = []
    for pattern in DOCUMENTS:
        found.extend(sorted(root.glob(pattern)))
    return found


def blocks(document: Path, root: Path = ROOT) -> list[Block]:
    """The shell blocks of ``document`` in order; a skip mark applies to the fence right after it."""
    out: list[Block] = []
    lines = document.read_text(encoding="utf-8").splitlines()
    name = document.relative_to(root).as_posix()
    inside: str | None = None
    start, body, skip, pending = 0, [], None, None
    for number, line in enumerate(lines, start=1):
        fence = FENCE.match(line.strip()) if line.startswith("```") else None
        if inside is None:
            mark = SKIP.match(line.strip())
            if mark:
                pending = mark.group("reason")
                continue
            if fence:
                inside, start, body, skip, pending = fence.group(1), number, [], pending, None
            elif line.strip():
                pending = None  # a mark belongs to the fence directly below it
            continue
        if fence and not fence.group(1):
            if inside in SHELLS and any(b.strip() and not b.lstrip().startswith("#") for b in body):
                out.append(Block(name, start, "\n".join(body) + "\n", skip))
            inside = None
            continue
        body.append(line)
    return out


def all_blocks(root: Path = ROOT) -> list[Block]:
    return [block for document in documents(root) for block in blocks(document, root)]
