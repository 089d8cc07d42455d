"""Every built-in component passes the conformance checks offered to plugin authors."""

from __future__ import annotations

import importlib.util

import pytest
import torch

from gns_framework import testing
from gns_framework.plugins import load_registry

REGISTRY = load_registry()
HAS_TORCH_CLUSTER = importlib.util.find_spec("torch_cluster") is not None
PROCESSOR_PARAMS = {"message_passing_steps": 2}


@pytest.mark.parametrize("name", REGISTRY.names("processor"))
def test_processor_conforms(name):
    testing.check_processor(REGISTRY.get("processor", name), PROCESSOR_PARAMS)


@pytest.mark.parametrize("name", REGISTRY.names("encoder"))
def test_encoder_conforms(name):
    testing.check_encoder(REGISTRY.get("encoder", name))


@pytest.mark.parametrize("name", REGISTRY.names("decoder"))
def test_decoder_conforms(name):
    testing.check_decoder(REGISTRY.get("decoder", name))


@pytest.mark.parametrize("name", REGISTRY.names("integrator"))
def test_integrator_conforms(name):
    testing.check_integrator(REGISTRY.get("integrator", name))


@pytest.mark.parametrize("name", REGISTRY.names("material"))
def test_material_conforms(name):
    testing.check_material(REGISTRY.get("material", name))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("name", REGISTRY.names("graph_builder"))
def test_graph_builder_conforms(name, dim):
    if name == "radius_torch_cluster" and not HAS_TORCH_CLUSTER:
        pytest.skip("torch-cluster is not installed")
    testing.check_graph_builder(REGISTRY.get("graph_builder", name), scene=testing.small_scene(dim))


@pytest.mark.parametrize("periodic", [(True, False), (True, True)])
def test_periodic_builder_conforms_on_periodic_scenes(periodic):
    scene = testing.small_scene(2, periodic=periodic)
    testing.check_graph_builder(REGISTRY.get("graph_builder", "periodic_radius"), scene=scene)


class _BrokenIntegrator(REGISTRY.get("integrator", "semi_implicit_euler")):
    name = "broken"

    def target(self, position_sequence, next_position):
        return 2 * super().target(position_sequence, next_position)


def test_integrator_check_catches_a_wrong_inverse():
    with pytest.raises(AssertionError, match="target"):
        testing.check_integrator(_BrokenIntegrator)


class _CrossTalkProcessor(REGISTRY.get("processor", "interaction_network")):
    name = "cross_talk"

    def forward(self, node_latent, edge_latent, graph):
        node_latent, edge_latent = super().forward(node_latent, edge_latent, graph)
        return node_latent + node_latent[:1], edge_latent


def test_processor_check_catches_broken_permutation_equivariance():
    with pytest.raises(AssertionError, match="permutation"):
        testing.check_processor(_CrossTalkProcessor, PROCESSOR_PARAMS)


class _EdgeOnlyParameterProcessor(REGISTRY.get("processor", "interaction_network")):
    """A last edge update that nothing downstream reads, as graph_attention had: DDP refuses its parameters."""

    name = "edge_only_parameter"

    def __init__(self, params, sizes):
        super().__init__(params, sizes)
        self.final_edge_update = torch.nn.Linear(sizes.latent, sizes.latent)

    def forward(self, node_latent, edge_latent, graph):
        node_latent, edge_latent = super().forward(node_latent, edge_latent, graph)
        return node_latent, edge_latent + self.final_edge_update(edge_latent)


def test_processor_check_catches_a_parameter_only_the_edge_output_depends_on():
    with pytest.raises(AssertionError, match="final_edge_update"):
        testing.check_processor(_EdgeOnlyParameterProcessor, PROCESSOR_PARAMS)
