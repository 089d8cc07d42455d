"""Every benchmark's, script's and command's ``--help`` can be printed: argparse expands each help text with ``%``
formatting, so a bare ``%`` (as in "disagreement, %") breaks ``--help`` only when someone asks for it.
Checked statically (importing each script would import torch 40 times)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted(
    [
        *ROOT.glob("benchmarks/*.py"),
        *ROOT.glob("scripts/*.py"),
        *ROOT.glob("gns_framework/cli/**/*.py"),
        *ROOT.glob("plugins/**/commands/**/*.py"),
    ]
)


def help_texts(source: str) -> list[tuple[int, str]]:
    """(line, text) of every literal ``help=`` given to a call in ``source``."""
    texts = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            for keyword in node.keywords:
                if keyword.arg == "help" and isinstance(keyword.value, ast.Constant):
                    texts.append((node.lineno, str(keyword.value.value)))
    return texts


def expandable(text: str) -> bool:
    """Whether argparse can expand ``text`` (it formats it with ``%`` and the action's fields)."""
    try:
        text % defaultdict(str)
    except (ValueError, TypeError, KeyError):
        return False
    return True


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_help_text_expands(script):
    bad = [f"line {line}: {text!r}" for line, text in help_texts(script.read_text()) if not expandable(text)]
    assert not bad, f"{script.relative_to(ROOT)}: a bare % in a help text breaks --help (write %%): {bad}"


def test_the_check_catches_a_bare_percent_and_passes_escaped_ones():
    assert not expandable("disagreement that flags a rollout, %")
    assert expandable("disagreement that flags a rollout, %%") and expandable("default %(default)s")
    source = 'p.add_argument("--x", help="in %")\np.add_argument("--y", help="fine")'
    assert [text for _, text in help_texts(source)] == ["in %", "fine"]
