"""Every built-in component passes the conformance checks offered to plugin authors."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch

from gns_framework import testing
from gns_framework.contracts import GroundTruthSimulator
from gns_framework.data.trajectory import Trajectory
from gns_framework.ground_truth.sampling import sample_scene
from gns_framework.ground_truth.scene_spec import SceneSpec
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
    if name == "no_edges":
        pytest.skip("builds no edges by design (tests/builtins/graph_builders/test_no_edges.py)")
    testing.check_graph_builder(REGISTRY.get("graph_builder", name), setup=testing.small_scene(dim))


@pytest.mark.parametrize("periodic", [(True, False), (True, True)])
def test_periodic_builder_conforms_on_periodic_scenes(periodic):
    setup = testing.small_scene(2, periodic=periodic)
    testing.check_graph_builder(REGISTRY.get("graph_builder", "periodic_radius"), setup=setup)


def test_check_graph_builder_still_takes_the_setup_as_scene_with_a_warning():
    with pytest.warns(DeprecationWarning, match=r"check_graph_builder\(scene=...\) is now check_graph_builder\(setup="):
        testing.check_graph_builder(REGISTRY.get("graph_builder", "radius"), scene=testing.small_scene(3))


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


@pytest.mark.parametrize("name", REGISTRY.names("dataset"))
def test_dataset_conforms(name):
    testing.check_dataset(REGISTRY.get("dataset", name))


class _ReorderingLayout(REGISTRY.get("dataset", "safe")):
    """Reads a split's trajectories back in reverse order."""

    name = "reordering"

    def split(self, name):
        return list(super().split(name))[::-1]


def test_dataset_check_catches_a_layout_that_reorders_trajectories():
    with pytest.raises(AssertionError, match="positions changed on the round trip"):
        testing.check_dataset(_ReorderingLayout)


def test_dataset_check_of_a_read_only_layout_needs_a_folder():
    class ReadOnly(_ReorderingLayout):
        name = "read_only"
        writable = False

    with pytest.raises(AssertionError, match="pass path="):
        testing.check_dataset(ReadOnly)


def _material(**facts):
    base = {
        "name": "grit",
        "particle_type": 12,
        "constitutive_model": "drucker_prager",
        "physical_parameters": {"density": 2000.0},
    }
    return type("Grit", (REGISTRY.get("material", "sand"),), {**base, **facts})


def test_a_well_formed_simulatable_material_conforms():
    testing.check_material(_material())


@pytest.mark.parametrize(
    "facts, message",
    [
        ({"constitutive_model": "mohr_coulomb"}, "unknown constitutive_model 'mohr_coulomb'.*drucker_prager"),
        ({"physical_parameters": {"density": -1.0}}, r"physical_parameters\['density'\] must be > 0"),
        ({"physical_parameters": {"density": float("nan")}}, "must be a finite number"),
        ({"particle_type": 5000}, "particle_type must be an int in 0..1023"),
        ({"particle_type": -1}, "particle_type must be an int in 0..1023"),
        ({"kinematic": True, "granular": True}, "a kinematic material is not granular"),
    ],
)
def test_material_check_refuses(facts, message):
    with pytest.raises(AssertionError, match=message):
        testing.check_material(_material(**facts))


class _Dropping(GroundTruthSimulator):
    """A toy simulator: the scene's particles fall at a rate drawn from the seed (or not, when sloppy)."""

    name = "dropping"
    constitutive_models = ("drucker_prager",)
    sloppy = False

    def simulate(self, scene, seed):
        sample = sample_scene(scene, seed)
        rng = np.random.default_rng(None if self.sloppy else seed)
        start = np.concatenate([body.position for body in sample.bodies])
        lower = np.asarray(scene.domain.bounds)[:, 0]
        rate = rng.uniform(0.001, 0.002)
        frames = [np.maximum(start - rate * t * np.eye(scene.dim)[-1], lower) for t in range(scene.time.frames)]
        return Trajectory(np.asarray(frames, np.float32), sample.particle_type(self.materials))


SAND_SCENE = {
    "name": "conformance",
    "dim": 2,
    "domain": {"bounds": [[0.0, 0.4], [0.0, 0.4]], "grid": 16},
    "time": {"frame_dt": 0.0025, "substeps": 10, "frames": 6},
    "blocks": [{"material": "sand", "position": [0.1, 0.0], "size": [0.1, 0.1]}],
}


def test_simulator_check_passes_a_conforming_simulator_and_catches_a_nondeterministic_one():
    scene = SceneSpec.model_validate(SAND_SCENE)
    materials = {name: REGISTRY.get("material", name) for name in REGISTRY.names("material")}
    testing.check_simulator(_Dropping, scene, materials)
    sloppy = type("Sloppy", (_Dropping,), {"name": "sloppy", "sloppy": True})
    with pytest.raises(AssertionError, match="same seed gave different trajectories"):
        testing.check_simulator(sloppy, scene, materials)
    with pytest.raises(AssertionError, match=r"cannot run the scene.*constitutive model 'weakly_compressible'"):
        water = {**SAND_SCENE, "blocks": [{**SAND_SCENE["blocks"][0], "material": "water"}]}
        testing.check_simulator(_Dropping, SceneSpec.model_validate(water), materials)
