"""Importing the package or asking ``gns --help`` loads no heavy optional package."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("mlflow", "meshio", "vtk", "warp", "matplotlib", "torch_geometric", "torch_cluster")

PROBE = """
import json, sys
{body}
print(json.dumps(sorted(m.split('.')[0] for m in sys.modules)))
"""

CASES = {
    "import gns_framework": "import gns_framework",
    "gns --help": (
        "from gns_framework.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass"
    ),
    "gns plugins": "from gns_framework.cli import main\nmain(['plugins'])",
}


@pytest.mark.parametrize("case", CASES)
def test_no_heavy_package_is_imported(case):
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(body=CASES[case])], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    loaded = set(json.loads(out.strip().splitlines()[-1]))
    assert not loaded & set(HEAVY), f"{case} imported {sorted(loaded & set(HEAVY))}"


def test_gns_help_does_not_import_torch():
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(body=CASES["gns --help"])], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    assert "torch" not in json.loads(out.strip().splitlines()[-1])
