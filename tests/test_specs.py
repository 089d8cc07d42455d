"""ComponentSpec: a registered name plus that component's parameters, as recipes and scene specs write them."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from gns_framework.specs import ComponentSpec


def test_everything_but_the_name_is_the_components_params():
    spec = ComponentSpec.model_validate(
        {"name": "interaction_network", "message_passing_steps": 10, "edge_block": "plain"}
    )
    assert spec.name == "interaction_network"
    assert spec.params == {"message_passing_steps": 10, "edge_block": "plain"}


def test_a_spec_with_only_a_name_has_no_params():
    assert ComponentSpec(name="mlp").params == {}


def test_params_is_a_copy_the_caller_may_change():
    spec = ComponentSpec(name="knn", k=6)
    spec.params["k"] = 99
    assert spec.params == {"k": 6}


def test_a_number_written_as_the_name_is_its_text():
    # YAML reads `name: 1e5` as a float; the name is what was written, not a type error.
    assert ComponentSpec.model_validate({"name": 7}).name == "7"
    assert ComponentSpec.model_validate({"name": 1e5}).name == "100000.0"


def test_the_name_is_required():
    with pytest.raises(ValidationError, match="name"):
        ComponentSpec.model_validate({"k": 6})


def test_importing_it_loads_nothing_else_of_gns_framework():
    # Recipes, scene specs and the registry all import it: it must depend on none of them.
    code = "import sys, gns_framework.specs; print(sorted(m for m in sys.modules if m.startswith('gns_framework.')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['gns_framework.specs']"
