"""The periodic radius graph: minimum-image neighbours through faces, edges and corners of the box."""

from __future__ import annotations

import pytest
import torch
from graph_cases import RADIUS, REGISTRY, brute_force_radius, build, edge_set, random_positions, scenes
from hypothesis import given, settings

from gns_framework.contracts import ModelSetup
from gns_framework.errors import RecipeError
from gns_framework.testing import small_scene


@settings(max_examples=40, deadline=None)
@given(scenes)
def test_periodic_radius_is_the_minimum_image_radius_graph(case):
    dim, counts, seed, _ = case
    position, batch = random_positions(dim, counts, seed, 1.0)
    scene = small_scene(dim, RADIUS, periodic=(True,) * dim)
    graph = build("periodic_radius", scene, position, batch, len(counts))
    assert edge_set(graph) == brute_force_radius(position, batch, RADIUS, box_length=1.0)
    assert float(torch.linalg.vector_norm(graph.displacement, dim=-1).max()) < RADIUS


def test_periodic_radius_connects_across_the_face_only_along_periodic_dimensions():
    position = torch.tensor([[0.01, 0.5], [0.99, 0.5], [0.5, 0.01], [0.5, 0.99]], dtype=torch.float64)
    batch = torch.zeros(4, dtype=torch.long)
    graph = build("periodic_radius", small_scene(2, RADIUS, periodic=(True, False)), position, batch, 1)
    assert edge_set(graph) - {(i, i) for i in range(4)} == {(0, 1), (1, 0)}
    across = (graph.senders == 1) & (graph.receivers == 0)
    assert torch.allclose(graph.displacement[across], torch.tensor([[-0.02, 0.0]], dtype=torch.float64))


def test_periodic_radius_refuses_a_box_shorter_than_two_radii():
    with pytest.raises(RecipeError, match="2R"):
        REGISTRY.get("graph_builder", "periodic_radius")(
            REGISTRY.get("graph_builder", "periodic_radius").Params(), small_scene(2, 0.6, periodic=(True, True))
        )


def test_particles_at_opposite_corners_connect_through_the_diagonal_image():
    # (0.02, 0.02) and (0.98, 0.97) are 0.064 apart through the corner, farther through either face alone.
    position = torch.tensor([[0.02, 0.02], [0.98, 0.97]], dtype=torch.float64)
    graph = build("periodic_radius", small_scene(2, RADIUS, periodic=(True, True)), position, torch.zeros(2).long(), 1)
    assert edge_set(graph) == {(0, 0), (1, 0), (0, 1), (1, 1)}
    # Edges sorted by (receiver, sender): 0 <- 0, 0 <- 1, 1 <- 0, 1 <- 1; the displacements are the minimum images.
    expected = torch.tensor([[0.0, 0.0], [-0.04, -0.05], [0.04, 0.05], [0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(graph.displacement, expected, rtol=0, atol=1e-12)


def test_a_box_that_does_not_start_at_zero_wraps_at_its_own_faces():
    # x wraps on [-1, 1): -0.99 and 0.98 are 0.03 apart through the face at +-1; y is walled.
    scene = ModelSetup(
        dim=2, bounds=((-1.0, 1.0), (0.0, 1.0)), connectivity_radius=0.1, particle_types=(5,), periodic=(True, False)
    )
    position = torch.tensor([[-0.99, 0.5], [0.98, 0.5], [0.0, 0.5]], dtype=torch.float64)
    graph = build("periodic_radius", scene, position, torch.zeros(3).long(), 1)
    assert edge_set(graph) - {(i, i) for i in range(3)} == {(0, 1), (1, 0)}
    torch.testing.assert_close(
        graph.displacement[(graph.senders == 1) & (graph.receivers == 0)],
        torch.tensor([[-0.03, 0.0]], dtype=torch.float64),
        rtol=0,
        atol=1e-12,
    )


def test_positions_outside_the_box_count_as_their_wrapped_images():
    # A particle stored one or two box lengths away is the same particle: same edges, same displacements.
    position, batch = random_positions(2, [30], seed=2, spread=1.0)
    scene = small_scene(2, RADIUS, periodic=(True, True))
    inside = build("periodic_radius", scene, position, batch, 1)
    shifts = torch.randint(-2, 3, position.shape, generator=torch.Generator().manual_seed(0)).double()
    outside = build("periodic_radius", scene, position + shifts, batch, 1)
    assert torch.equal(outside.senders, inside.senders) and torch.equal(outside.receivers, inside.receivers)
    # Wrapping subtracts whole lengths of 1 from values below 3: a few ulps of 3.
    torch.testing.assert_close(outside.displacement, inside.displacement, rtol=0, atol=1e-14)


def test_ghosts_do_not_connect_particles_of_different_examples():
    position = torch.tensor([[0.01, 0.5], [0.99, 0.5]], dtype=torch.float64)
    graph = build("periodic_radius", small_scene(2, RADIUS, periodic=(True, True)), position, torch.tensor([0, 1]), 2)
    assert edge_set(graph) == {(0, 0), (1, 1)}


def test_without_periodic_dimensions_it_is_the_radius_graph():
    position, batch = random_positions(3, [20, 15], seed=4, spread=0.5)
    periodic = build("periodic_radius", small_scene(3, 0.15), position, batch, 2)
    plain = build("radius", small_scene(3, 0.15), position, batch, 2)
    for got, expected in zip(
        (periodic.senders, periodic.receivers, periodic.displacement),
        (plain.senders, plain.receivers, plain.displacement),
        strict=True,
    ):
        assert torch.equal(got, expected)
