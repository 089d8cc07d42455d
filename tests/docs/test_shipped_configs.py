"""Every shipped inversion config fits the model it names: the file loads, the model is shipped, and each
unknown's search bounds lie in what that model trained on (what ``gns invert`` checks before it runs).

Recipes are held to the data they name in tests/test_recipe_data.py; scenes load in
tests/ground_truth; a documented command that runs a config is run by test_doc_commands.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from doc_blocks import ROOT

from gns_framework.assembly.trained import load_trained
from gns_framework.inverse.config import load_invert_config
from gns_framework.inverse.solve import unknown_bounds_problems
from gns_framework.plugins import load_registry

CONFIGS = sorted((ROOT / "inversions").glob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_inversion_config_fits_its_model(path: Path):
    config, unknowns = load_invert_config(path)
    model_path = Path(config.model)
    assert model_path.is_file(), f"{path}: model {model_path} is not shipped"
    model = load_trained(model_path, load_registry())
    assert model.envelope is not None, f"{path}: {model_path} records no envelope to check the bounds against"
    assert unknown_bounds_problems(model.envelope, unknowns) == [], path


def test_bounds_outside_the_trained_range_are_found():
    """The check itself: the friction bounds the shipped config had before issue 48 are refused."""
    config, unknowns = load_invert_config(ROOT / "inversions" / "sand_friction.yaml")
    model = load_trained(Path(config.model), load_registry())
    wide = {"friction": unknowns["friction"].model_copy(update={"bounds": (0.4, 1.0)})}
    problems = unknown_bounds_problems(model.envelope, wide)
    assert len(problems) == 1 and problems[0].startswith("unknowns.friction.bounds [0.4, 1]"), problems
