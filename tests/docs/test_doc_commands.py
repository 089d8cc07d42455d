"""Every documented command runs as written (scaled down for CI), in the documents' order.

Each fenced bash block of README.md, docs/*.md and models/README.md is one test,
run in a sandbox per document (:mod:`docs_sandbox`) that the document's earlier blocks
have filled, with ``set -e``: a block fails when any of its commands fails or a
command's stated outputs (``--out``, ``--gif``, ``--plot``, ...) are missing. Blocks
marked ``<!-- docs-test: skip: REASON -->`` in their document are reported as
skipped with that reason. ``GNS_DOCS_SCALE=full`` runs every command at its
documented size (hours).
"""

from __future__ import annotations

import json
import subprocess
import warnings
from pathlib import Path

import pytest
from doc_blocks import all_blocks
from docs_sandbox import make_sandbox

BLOCKS = all_blocks()
BLOCK_SECONDS = 900
PRELUDE = """set -eo pipefail
trap 'echo "docs-test: failed at line $((LINENO - 2)) of the block: $BASH_COMMAND" >&2' ERR
"""


class DocCommandNotRun(UserWarning):
    """A command inside a run block that the sandbox does not run, with the reason."""


@pytest.fixture(scope="session")
def sandboxes(tmp_path_factory):
    """document -> (folder, environment, log), made the first time one of its blocks runs."""
    cache = tmp_path_factory.mktemp("docs_data_cache")
    made: dict[str, tuple[Path, dict[str, str], Path]] = {}

    def get(document: str):
        if document not in made:
            folder = tmp_path_factory.mktemp(document.replace("/", "_").replace(".", "_"))
            log = folder / ".docs_test.jsonl"
            made[document] = (folder, make_sandbox(folder, log, cache), log)
        return made[document]

    return get


def test_the_documents_have_blocks():
    documents = {block.document for block in BLOCKS}
    assert {"README.md", "models/README.md", "docs/first_scene.md"} <= documents


@pytest.mark.parametrize("block", BLOCKS, ids=[block.name for block in BLOCKS])
def test_documented_block_runs(block, sandboxes):
    if block.skip:
        pytest.skip(f"{block.name} ({block.first_command()[:60]}): {block.skip}")
    folder, env, log = sandboxes(block.document)
    before = len(log.read_text().splitlines()) if log.exists() else 0
    result = subprocess.run(
        ["bash", "-c", PRELUDE + block.text],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=BLOCK_SECONDS,
    )
    entries = [json.loads(line) for line in log.read_text().splitlines()[before:]] if log.exists() else []
    for entry in entries:
        if "not_run" in entry:
            warnings.warn(
                DocCommandNotRun(f"{block.name}: {' '.join(entry['as_written'])}: {entry['not_run']}"), stacklevel=1
            )
    if result.returncode != 0:
        tail = (result.stdout[-2500:] + "\n" + result.stderr[-4000:]).strip()
        pytest.fail(f"{block.name}: exit {result.returncode}\n{tail}", pytrace=False)
