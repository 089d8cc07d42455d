"""The simulator candidates of ``gns evaluate`` re-simulate each test case with that case's own seed."""

from __future__ import annotations

import numpy as np
import yaml

from gns_framework.assembly.data import open_dataset
from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.config.recipe import DatasetSpec
from gns_framework.evaluation.candidates import cases_from_split, simulator_candidates
from gns_framework.ground_truth.generate import generate_dataset
from gns_framework.ground_truth.scene_spec import parse_scene
from gns_framework.plugins import load_registry

SCENE = """
name: tiny_collapse
dim: 2
domain: {bounds: [[0.0, 1.0], [0.0, 0.5]], grid: 16}
time: {frame_dt: 0.005, substeps: 10, frames: 10}
seed: 2
blocks:
  - material: sand
    position: [0.0, 0.0]
    size: [0.2, {range: [0.2, 0.3]}]
    properties: {friction: {range: [0.6, 0.8]}}
"""


def test_the_reference_setting_reproduces_every_case_whatever_the_key_order(tmp_path):
    registry = load_registry()
    scene = parse_scene(yaml.safe_load(SCENE), "scene")
    simulator = build_ground_truth_simulator(scene, registry, "scene")
    counts = {"train": 1, "valid": 0, "test": 3}
    generate_dataset(scene, simulator, tmp_path, registry.get("dataset", "safe"), counts, progress=False)
    dataset = open_dataset(DatasetSpec(path=str(tmp_path)), registry)
    cases = cases_from_split(dataset.split("test"))
    # The seed-named keys of this scene do not sort in generation order: a test of file order, not luck.
    assert [c.key for c in cases] != sorted(c.key for c in cases)
    (reference,) = simulator_candidates(dataset.metadata(), registry, cases, 3, [1.0], [1.0])
    for case in cases:
        np.testing.assert_array_equal(reference.simulate(case).position, case.position[3:])
