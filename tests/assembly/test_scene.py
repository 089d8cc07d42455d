"""A scene pays only for what it has: parameters per scene, kinematic rows never decoded."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from gns_framework.assembly.learned import build_learned_simulator
from gns_framework.config.recipe import ModelSpec
from gns_framework.contracts import ModelSetup
from gns_framework.data.batch import ParticleBatch
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.plugins import load_registry

REGISTRY = load_registry()
METADATA = DatasetMetadata(
    bounds=[(0.0, 1.0), (0.0, 1.0)],
    sequence_length=10,
    default_connectivity_radius=0.1,
    dim=2,
    dt=0.01,
    vel_mean=[0.0, 0.0],
    vel_std=[1e-3, 1e-3],
    acc_mean=[0.0, 0.0],
    acc_std=[1e-4, 1e-4],
)
WATER = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,))
REFERENCE = ModelSpec()
"""The paper's sizes: latent 128, two hidden layers of 128, 10 steps, type embedding 16."""
PERIODIC_REFERENCE = ModelSpec(graph_builder={"name": "periodic_radius"})

SCENES = {
    "water (one material, walls)": WATER,
    "water + rigid (two types)": dataclasses.replace(WATER, particle_types=(3, 5), kinematic_types=(3,)),
    "sand with friction (one property)": dataclasses.replace(WATER, particle_types=(6,), property_names=("friction",)),
    "water without walls": dataclasses.replace(WATER, walls=False),
    "water, periodic in x": dataclasses.replace(WATER, periodic=(True, False)),
}
EXPECTED_PARAMETERS = {
    "water (one material, walls)": 1_589_634,
    "water + rigid (two types)": 1_591_714,
    "sand with friction (one property)": 1_589_762,
    "water without walls": 1_589_122,
    "water, periodic in x": 1_589_378,
}


def simulator_for(scene: ModelSetup):
    return build_learned_simulator(scene, METADATA, PERIODIC_REFERENCE if scene.periodic_dims else REFERENCE, REGISTRY)


def parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@pytest.mark.parametrize("label", SCENES)
def test_reference_parameter_count_per_scene(label):
    simulator = simulator_for(SCENES[label])
    assert parameters(simulator) == EXPECTED_PARAMETERS[label]


def test_each_feature_costs_exactly_its_first_layer_columns():
    base = simulator_for(WATER)
    assert parameters(base.features) == 0 and base.features.type_embedding is None
    hidden, embedding = REFERENCE.mlp_hidden_size, REFERENCE.type_embedding_size
    extra = {label: parameters(simulator_for(s)) - parameters(base) for label, s in SCENES.items()}
    assert extra["water + rigid (two types)"] == 2 * embedding + embedding * hidden
    assert extra["sand with friction (one property)"] == 1 * hidden
    assert extra["water without walls"] == -4 * hidden
    assert extra["water, periodic in x"] == -2 * hidden


def test_kinematic_particles_are_not_decoded_nor_integrated():
    scene = SCENES["water + rigid (two types)"]
    model = ModelSpec(
        latent_size=16, mlp_hidden_size=16, processor={"name": "interaction_network", "message_passing_steps": 2}
    )
    torch.manual_seed(0)
    simulator = build_learned_simulator(scene, METADATA, model, REGISTRY).eval()
    n = 30
    sequence = torch.rand(n, 1, 2) + 1e-3 * torch.cumsum(torch.randn(n, 6, 2), 1)
    particle_type = torch.where(torch.arange(n) % 3 == 0, 3, 5)
    batch = ParticleBatch(sequence, particle_type, torch.zeros(n, dtype=torch.long), 1)
    prescribed = torch.rand(n, 2)
    decoded_rows = []
    simulator.decoder.register_forward_hook(lambda module, args, out: decoded_rows.append(args[0].shape[0]))

    with torch.no_grad():
        next_position = simulator.predict_next_position(batch, prescribed=prescribed)
        full = simulator.normalized_prediction(sequence, batch)
    moving = particle_type != 3
    assert decoded_rows == [int(moving.sum()), n]
    assert torch.equal(next_position[~moving], prescribed[~moving])
    reference = simulator.integrator.next_position(sequence, simulator.output_stats.denormalize(full))
    assert torch.allclose(next_position[moving], reference[moving], atol=1e-6)
    without = simulator.predict_next_position(batch)
    assert torch.equal(without[~moving], sequence[~moving, -1])
