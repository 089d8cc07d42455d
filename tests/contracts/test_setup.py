"""The learned model's setup (ModelSetup): its defaults and the properties derived from it; ModelSizes' default."""

from __future__ import annotations

import dataclasses

import pytest

from gns_framework.contracts import ModelSetup, ModelSizes

BOX_2D = ((0.0, 1.0), (0.0, 1.0))
BOX_3D = ((0.0, 1.0), (0.0, 0.5), (0.0, 2.0))


def _setup(**fields) -> ModelSetup:
    return ModelSetup(**{"dim": 2, "bounds": BOX_2D, "connectivity_radius": 0.05, "particle_types": (5,), **fields})


def test_the_defaults_are_the_reference_model_in_a_walled_box():
    setup = _setup()
    assert setup.history == 6 and setup.walls and setup.boundary_clamp_limit == 1.0
    assert setup.kinematic_types == () and setup.property_names == () and setup.context_size == 0
    assert setup.periodic == () and not setup.wall_conditions


@pytest.mark.parametrize("types, embedded", [((5,), False), ((3, 5), True), ((3, 5, 6), True)])
def test_a_type_embedding_is_used_only_with_more_than_one_type(types, embedded):
    setup = _setup(particle_types=types)
    assert setup.num_particle_types == len(types)
    assert setup.uses_type_embedding is embedded


@pytest.mark.parametrize(
    "dim, bounds, periodic, periodic_dims, wall_dims",
    [
        (2, BOX_2D, (), (), (0, 1)),  # no periodic entry: walls everywhere
        (2, BOX_2D, (False, False), (), (0, 1)),
        (2, BOX_2D, (True, False), (0,), (1,)),  # a channel: wraps along x, walls top and bottom
        (3, BOX_3D, (True, False, True), (0, 2), (1,)),
        (3, BOX_3D, (True, True, True), (0, 1, 2), ()),
    ],
)
def test_walls_bound_exactly_the_dimensions_that_do_not_wrap(dim, bounds, periodic, periodic_dims, wall_dims):
    setup = _setup(dim=dim, bounds=bounds, periodic=periodic)
    assert setup.periodic_dims == periodic_dims
    assert setup.wall_dims == wall_dims


def test_without_wall_features_no_dimension_has_walls():
    assert _setup(walls=False).wall_dims == ()
    assert _setup(walls=False, periodic=(True, False)).periodic_dims == (0,)


def test_a_setup_is_frozen_and_compares_by_value():
    # It is stored in every checkpoint and compared when one is loaded.
    assert _setup() == _setup() and _setup() != _setup(history=5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        _setup().history = 3


def test_model_sizes_measure_displacements_in_units_of_one_radius_by_default():
    sizes = ModelSizes(node_in=30, edge_in=3, latent=128, mlp_hidden=128, mlp_hidden_layers=2, output=2, dim=2)
    assert sizes.connectivity_radius == 1.0
    assert dataclasses.replace(sizes, connectivity_radius=0.015).connectivity_radius == 0.015
