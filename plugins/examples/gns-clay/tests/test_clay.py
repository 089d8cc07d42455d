"""The clay material conforms and is found through its entry point."""

from gns_example_clay import Clay

from gns_framework.plugins import load_registry
from gns_framework.testing import check_material


def test_clay_conforms():
    check_material(Clay)


def test_clay_is_registered_by_its_entry_point():
    entry = load_registry().entry("material", "clay")
    assert entry.cls is Clay
    assert entry.distribution == "gns-example-clay"


def test_weaker_clay_slumps_further_in_the_mpm():
    """The MLS-MPM moves clay with the undrained model: a column of half the strength runs out further and ends
    lower."""
    from pathlib import Path

    import numpy as np
    import yaml

    from gns_framework.assembly.ground_truth import build_ground_truth_simulator
    from gns_framework.ground_truth.scene_spec import parse_scene

    scene_file = Path(__file__).resolve().parents[4] / "scenes" / "clay_collapse_2d.yaml"
    raw = yaml.safe_load(scene_file.read_text())
    raw["time"]["frames"] = 60
    raw["blocks"][0]["size"] = [0.2, 0.3]
    registry = load_registry()
    ends = {}
    for cohesion in (0.4, 0.8):
        raw["blocks"][0]["properties"] = {"cohesion": cohesion}
        scene = parse_scene(raw, str(scene_file))
        trajectory = build_ground_truth_simulator(scene, registry, str(scene_file)).simulate(scene, 0)
        clay = trajectory.particle_type == Clay.particle_type
        assert np.allclose(trajectory.material_property[clay], cohesion)
        final = trajectory.position[-1][clay]
        ends[cohesion] = (final[:, 0].max(), final[:, 1].max())
    (weak_front, weak_top), (strong_front, strong_top) = ends[0.4], ends[0.8]
    assert weak_front > strong_front + 0.02 and weak_top < strong_top - 0.02, ends
