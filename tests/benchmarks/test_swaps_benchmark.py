"""benchmarks/swaps.py finds what each swap recipe changes and puts exactly that into the base recipe."""

from __future__ import annotations

from pathlib import Path

import yaml
from load_script import load_script

ROOT = Path(__file__).resolve().parents[2]
swaps = load_script("benchmarks/swaps.py")


def load(path: str) -> dict:
    return yaml.safe_load((ROOT / path).read_text())


def test_each_swap_recipe_changes_one_component_of_the_reference():
    reference = load("recipes/sand2d.yaml")
    found = {
        p.stem: swaps.swapped_component(yaml.safe_load(p.read_text()), reference)
        for p in sorted((ROOT / "recipes" / "swaps").glob("*.yaml"))
    }
    assert found["egnn"] == ("processor", {"name": "egnn", "message_passing_steps": 10})
    assert found["velocity_euler"][0] == "integrator" and found["knn"][0] == "graph_builder"
    assert found["clay2d"] is None, "clay2d changes the materials, not a component"
    assert all(f is not None for name, f in found.items() if name != "clay2d")


def test_a_variant_is_the_base_with_one_component_and_the_bases_model_size(tmp_path):
    base = load("recipes/sizes/sand2d_fast_3x32.yaml")
    raw = swaps.variant(
        base, "processor", {"name": "egnn", "message_passing_steps": 10}, tmp_path / "d", 50, 3, tmp_path / "run"
    )
    assert raw["model"]["processor"] == {"name": "egnn", "message_passing_steps": 3}
    assert {k: v for k, v in raw["model"].items() if k != "processor"} == {
        k: v for k, v in base["model"].items() if k != "processor"
    }
    assert raw["seed"] == 3 and raw["training"]["steps"] == 50 and raw["dataset"]["path"] == str(tmp_path / "d")
    assert base["model"]["processor"]["name"] == "interaction_network", "the base is not changed"
