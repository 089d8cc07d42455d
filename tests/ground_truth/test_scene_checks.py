"""The checks every ground-truth simulator shares before its own: dimension, materials (installed, moved by the
simulator, kinematic exactly for obstacles) and block properties; then the simulator's own check."""

from __future__ import annotations

import copy
from collections.abc import Sequence

from scene_builders import mixed

from gns_framework.contracts import GroundTruthSimulator, Material, MaterialProperty, Params
from gns_framework.ground_truth.scene_checks import scene_problems
from gns_framework.ground_truth.scene_spec import parse_scene


def _material(name: str, model: str | None, kinematic: bool = False, properties=()) -> type[Material]:
    declared = tuple(MaterialProperty(p, p) for p in properties)
    facts = {"name": name, "particle_type": 0, "constitutive_model": model, "kinematic": kinematic}
    return type(name.title(), (Material,), {**facts, "properties": declared})


# The materials of the mixed scene, as stand-ins with the constitutive models this simulator moves.
MATERIALS = {
    "water": _material("water", "fluid"),
    "sand": _material("sand", "granular", properties=("friction",)),
    "goop": _material("goop", "fluid"),
    "rigid": _material("rigid", "rigid", kinematic=True),
}


class Stub(GroundTruthSimulator):
    name = "stub"
    dims = (2,)
    constitutive_models = ("fluid", "granular", "rigid")
    own: Sequence[tuple[str, str]] = ()  # a test sets its own on the instance

    def check(self, scene):
        return list(self.own)

    def simulate(self, scene, seed):
        raise NotImplementedError


def _problems(raw: dict, materials=MATERIALS) -> dict[str, str]:
    simulator = Stub(Params(), materials)
    return dict(scene_problems(simulator, parse_scene(raw)))


def test_a_scene_the_simulator_can_run_has_no_problem():
    assert _problems(mixed()) == {}


def test_the_simulators_own_problems_come_after_the_shared_ones():
    raw = mixed()
    raw["blocks"][0]["material"] = "lava"
    simulator = Stub(Params(), MATERIALS)
    simulator.own = [("time.substeps", "too few")]
    found = scene_problems(simulator, parse_scene(raw))
    assert [where for where, _ in found] == ["blocks[0].material", "time.substeps"]


def test_a_dimension_the_simulator_does_not_support():
    raw = mixed()
    raw.update(dim=3, domain={"bounds": [[0.0, 0.5]] * 3, "grid": 16})
    raw["blocks"] = [{"material": "water", "position": [0.0, 0.0, 0.0], "size": [0.1, 0.1, 0.1]}]
    raw["obstacles"] = []
    assert _problems(raw) == {"dim": "simulator 'stub' supports dim (2,), got 3"}


def test_an_unknown_material_lists_the_installed_ones():
    raw = mixed()
    raw["blocks"][2]["material"] = "lava"
    assert _problems(raw) == {"blocks[2].material": "unknown material 'lava' (installed: goop, rigid, sand, water)"}
    uses = [("blocks[0]", "water"), ("blocks[1]", "sand"), ("blocks[2]", "lava"), ("obstacles[0]", "rigid")]
    assert _problems(raw, materials={}) == {
        f"{where}.material": f"unknown material {name!r} (installed: none installed)" for where, name in uses
    }


def test_a_material_whose_model_the_simulator_does_not_move():
    materials = {**MATERIALS, "goop": _material("goop", "viscoplastic")}
    assert _problems(mixed(), materials) == {
        "blocks[2].material": "material 'goop' has constitutive model 'viscoplastic'; simulator 'stub' supports "
        "fluid, granular, rigid"
    }


def test_obstacles_take_kinematic_materials_and_blocks_take_the_others():
    raw = copy.deepcopy(mixed())
    raw["obstacles"][0]["material"] = "sand"
    raw["blocks"][0]["material"] = "rigid"
    assert _problems(raw) == {
        "blocks[0].material": "material 'rigid' is kinematic: obstacles take kinematic materials",
        "obstacles[0].material": "material 'sand' is not kinematic: obstacles take kinematic materials",
    }


def test_a_block_sets_only_the_properties_its_material_declares():
    raw = mixed()
    raw["blocks"][1]["properties"] = {"friction": 0.5, "cohesion": 1.0}
    raw["blocks"][0]["properties"] = {"viscosity": 1.0}
    assert _problems(raw) == {
        "blocks[1].properties.cohesion": "material 'sand' has no property 'cohesion' (it has: friction)",
        "blocks[0].properties.viscosity": "material 'water' has no property 'viscosity' (it has: none)",
    }


def test_the_properties_of_an_unknown_material_are_not_judged_again():
    raw = mixed()
    raw["blocks"][1]["material"] = "clay"  # keeps its friction property: only the material is reported
    assert list(_problems(raw)) == ["blocks[1].material"]
