"""Node features: sized from the scene (no type embedding for one material), columns in the reference's order."""

from __future__ import annotations

import torch

from gns_framework.contracts import ModelSetup
from gns_framework.model.features import FeatureBuilder, node_feature_size
from gns_framework.model.normalization import Stats


def _scene(**kw):
    base = dict(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,))
    return ModelSetup(**{**base, **kw})


def test_single_material_scene_has_no_type_embedding():
    stats = Stats([0.0, 0.0], [1.0, 1.0])
    single = FeatureBuilder(_scene(), stats, 16)
    multi = FeatureBuilder(_scene(particle_types=(3, 5, 6)), stats, 16)
    assert single.type_embedding is None and sum(p.numel() for p in single.parameters()) == 0
    assert multi.type_embedding.weight.shape == (3, 16)
    assert node_feature_size(_scene(), 16) == 10 + 4
    assert node_feature_size(_scene(particle_types=(3, 5, 6), property_names=("friction",)), 16) == 10 + 4 + 16 + 1
    assert node_feature_size(_scene(walls=False), 16) == 10


def test_node_features_column_order():
    scene = _scene(particle_types=(5, 6), property_names=("friction",))
    builder = FeatureBuilder(scene, Stats([0.0, 0.0], [1.0, 1.0]), 4)
    sequence = torch.linspace(0.2, 0.3, 12).reshape(1, 6, 2).repeat(2, 1, 1)
    features = builder.node_features(sequence, torch.tensor([5, 6]), torch.tensor([[0.5], [0.7]]))
    velocity = sequence[:, 1:] - sequence[:, :-1]
    torch.testing.assert_close(features[:, :10], velocity.reshape(2, 10))
    walls = torch.cat([sequence[:, -1], 1 - sequence[:, -1]], 1) / 0.1
    torch.testing.assert_close(features[:, 10:14], walls.clamp(-1, 1))
    torch.testing.assert_close(features[:, 14:18], builder.type_embedding.weight)
    torch.testing.assert_close(features[:, 18], torch.tensor([0.5, 0.7]))


def test_walls_come_from_each_example_domain_when_the_data_gives_one():
    """Two particles at the same place in boxes of other sizes see their own walls."""
    scene = _scene(boundary_clamp_limit=20.0)
    builder = FeatureBuilder(scene, Stats([0.0, 0.0], [1.0, 1.0]), 4)
    sequence = torch.full((2, 6, 2), 0.4)
    bounds = torch.tensor([[[0.0, 0.5], [0.0, 0.5]], [[0.0, 2.0], [0.0, 1.0]]])
    features = builder.node_features(sequence, torch.tensor([5, 5]), bounds=bounds)
    expected = torch.tensor([[0.4, 0.4, 0.1, 0.1], [0.4, 0.4, 1.6, 0.6]]) / 0.1
    torch.testing.assert_close(features[:, 10:14], expected)
    default = builder.node_features(sequence, torch.tensor([5, 5]))
    torch.testing.assert_close(default[:, 10:14], torch.tensor([[0.4, 0.4, 0.6, 0.6]] * 2) / 0.1)


def test_wall_conditions_follow_the_distance_columns_face_by_face():
    scene = _scene(wall_conditions=True)
    assert node_feature_size(scene, 16) == 10 + 4 + 4
    builder = FeatureBuilder(scene, Stats([0.0, 0.0], [1.0, 1.0]), 4)
    walls = torch.tensor([[[0.1, 0], [0.2, 0], [0.3, 0], [0.4, 0]]] * 3)  # x_min, x_max, y_min, y_max
    features = builder.node_features(torch.rand(3, 6, 2), torch.tensor([5, 5, 5]), walls=walls)
    # distance columns are [x lower, y lower, x upper, y upper]; the friction columns follow that order
    torch.testing.assert_close(features[:, 14:18], torch.tensor([[0.1, 0.3, 0.2, 0.4]] * 3))
    periodic_x = FeatureBuilder(_scene(wall_conditions=True, periodic=(True, False)), Stats([0.0, 0.0], [1.0, 1.0]), 4)
    features = periodic_x.node_features(torch.rand(3, 6, 2), torch.tensor([5, 5, 5]), walls=walls)
    torch.testing.assert_close(features[:, 12:14], torch.tensor([[0.3, 0.4]] * 3))


def test_wall_conditions_without_recorded_walls_are_refused():
    builder = FeatureBuilder(_scene(wall_conditions=True), Stats([0.0, 0.0], [1.0, 1.0]), 4)
    import pytest

    with pytest.raises(ValueError, match="records no walls"):
        builder.node_features(torch.rand(3, 6, 2), torch.tensor([5, 5, 5]))
