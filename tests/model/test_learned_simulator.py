"""The learned simulator: kinematic particles follow their prescribed path, and training targets are the paper's."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from gns_framework.assembly.learned import build_learned_simulator
from gns_framework.config.recipe import ModelSpec
from gns_framework.contracts import ModelSetup
from gns_framework.data.batch import ParticleBatch
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.model.learned_simulator import LearnedSimulator
from gns_framework.model.rollout import rollout
from gns_framework.plugins import load_registry


def simulator():
    scene = ModelSetup(
        dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.2, particle_types=(3, 5), kinematic_types=(3,)
    )
    metadata = DatasetMetadata(
        bounds=[(0.0, 1.0), (0.0, 1.0)],
        sequence_length=10,
        default_connectivity_radius=0.2,
        dim=2,
        dt=0.01,
        vel_mean=[0.0, 0.0],
        vel_std=[0.01, 0.01],
        acc_mean=[0.0, 0.0],
        acc_std=[0.001, 0.001],
    )
    torch.manual_seed(0)
    spec = ModelSpec(
        latent_size=8,
        mlp_hidden_size=8,
        mlp_hidden_layers=1,
        type_embedding_size=2,
        processor={"name": "interaction_network", "message_passing_steps": 1},
    )
    return build_learned_simulator(scene, metadata, spec, load_registry()).eval()


def batch(n=12, history=6):
    generator = torch.Generator().manual_seed(1)
    start = 0.2 + 0.6 * torch.rand(n, 1, 2, generator=generator)
    steps = 0.003 * torch.randn(n, history, 2, generator=generator).cumsum(1)
    types = torch.tensor([3, 5] * (n // 2))
    return ParticleBatch(
        start + steps, types, torch.zeros(n, dtype=torch.long), 1, next_position=(start + steps)[:, -1] + 0.001
    )


def test_kinematic_particles_take_their_prescribed_positions_and_the_rest_are_predicted():
    model, current = simulator(), batch()
    prescribed = torch.full((12, 2), 0.5)
    with torch.no_grad():
        nxt = model.predict_next_position(current, prescribed=prescribed)
        held = model.predict_next_position(current)
    kinematic = current.particle_type == 3
    assert torch.equal(nxt[kinematic], prescribed[kinematic])
    assert torch.equal(held[kinematic], current.position_sequence[kinematic, -1]), "without a path they stay put"
    assert torch.equal(nxt[~kinematic], held[~kinematic]), "moving particles do not depend on the prescribed path"
    assert not torch.equal(nxt[~kinematic], current.position_sequence[~kinematic, -1])


def test_the_training_target_corrects_the_velocity_noise_but_not_the_position_noise():
    # Sanchez-Gonzalez et al. 2020, Sec. 3: the target next position moves with the last input's noise.
    model, current = simulator(), batch()
    noise = torch.zeros_like(current.position_sequence)
    noise[:, -1] = 1e-3
    _, target = model(current, noise)
    noisy = current.position_sequence + noise
    expected = model.integrator.target(noisy, current.next_position + noise[:, -1])
    torch.testing.assert_close(target, model.output_stats.normalize(expected))
    _, clean = model(current, torch.zeros_like(noise))
    assert not torch.allclose(target, clean), "the noise changes the target (through the velocity it implies)"


def test_the_predicted_mask_is_the_non_kinematic_types():
    model = simulator()
    assert model.predicted_mask(torch.tensor([3, 5, 5, 3])).tolist() == [False, True, True, False]


def test_the_setup_under_its_old_name_scene_warns_and_is_the_setup():
    model = simulator()
    with pytest.warns(DeprecationWarning, match=r"LearnedSimulator\.scene is now \.setup; the old name goes in 0\.3"):
        assert model.scene is model.setup
    with pytest.warns(DeprecationWarning, match=r"FeatureBuilder\.scene is now \.setup"):
        assert model.features.scene is model.setup
    assert model.setup.particle_types == (3, 5) and model.features.setup is model.setup


def test_a_simulator_still_takes_its_setup_as_scene_with_a_warning():
    model = simulator()
    parts = {name: getattr(model, name) for name in ("features", "graph_builder", "encoder", "processor", "decoder")}
    parts |= {"integrator": model.integrator, "output_stats": model.output_stats}
    with pytest.warns(DeprecationWarning, match=r"LearnedSimulator\(scene=...\) is now LearnedSimulator\(setup=...\)"):
        again = LearnedSimulator(scene=model.setup, **parts)
    assert again.setup is model.setup


def test_training_and_rollout_read_no_deprecated_scene():
    """The package itself reads the setup by its new name: a step and a rollout warn of nothing deprecated."""
    model, current = simulator(), batch()
    generator = np.random.default_rng(2)
    position = 0.3 + 0.4 * generator.random((1, 12, 2)) + 0.002 * generator.standard_normal((9, 12, 2)).cumsum(0)
    trajectory = Trajectory(position.astype(np.float32), np.array([3, 5] * 6), None, None, "t")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        model(current, torch.zeros_like(current.position_sequence))
        with torch.no_grad():
            rollout(model, trajectory, steps=2)
