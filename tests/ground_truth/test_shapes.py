"""Shapes as particles: rotations in the x-y plane, polygon orientation and containment, polygon lattices,
inclined-plane layers and the in-bounds test."""

from __future__ import annotations

import numpy as np
import pytest

from gns_framework.ground_truth.shapes import (
    counter_clockwise,
    inside,
    plane_layer,
    polygon_contains,
    polygon_lattice,
    rotate_xy,
)

# Coordinates here are of order 1 and each result takes a few float64 operations: 1e-12 is loose for
# rounding and tight for any geometric mistake.
ATOL = 1e-12
SQUARE_CW = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]])


def test_a_quarter_turn_is_counter_clockwise_about_the_centre():
    points = np.array([[2.0, 1.0], [1.0, 1.0]])
    turned = rotate_xy(points, 90.0, centre=np.array([1.0, 1.0]))
    np.testing.assert_allclose(turned, [[1.0, 2.0], [1.0, 1.0]], atol=ATOL)  # the centre stays put


def test_in_3d_the_turn_is_about_z_and_leaves_z_alone():
    turned = rotate_xy(np.array([[1.0, 0.0, 0.7]]), 30.0, centre=np.zeros(3))
    np.testing.assert_allclose(turned, [[np.cos(np.pi / 6), 0.5, 0.7]], atol=ATOL)


def test_no_turn_returns_the_points_untouched():
    points = np.array([[0.3, 0.4]])
    assert rotate_xy(points, 0.0, centre=np.zeros(2)) is points


def test_vertices_come_back_counter_clockwise():
    ccw = counter_clockwise(SQUARE_CW)
    np.testing.assert_array_equal(ccw, SQUARE_CW[::-1])
    assert counter_clockwise(ccw) is ccw  # already counter-clockwise: kept as given


def test_polygon_contains_follows_the_even_odd_rule_for_a_concave_outline():
    # An L: the unit square without its upper-right quarter.
    ell = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.5], [0.5, 0.5], [0.5, 1.0], [0.0, 1.0]])
    points = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75], [1.5, 0.25], [-0.1, 0.5]])
    assert polygon_contains(points, ell).tolist() == [True, True, True, False, False, False]
    # Orientation does not matter, and a 3D point is judged by its x-y.
    assert polygon_contains(np.array([[0.75, 0.25, 9.0]]), ell[::-1]).tolist() == [True]


def test_a_polygon_lattice_holds_the_cell_centres_inside():
    square = np.array([[0.0, 0.0], [0.4, 0.0], [0.4, 0.4], [0.0, 0.4]])
    points = polygon_lattice(square, 0.1)
    assert points.shape == (16, 2)
    np.testing.assert_allclose(np.unique(points[:, 0]), [0.05, 0.15, 0.25, 0.35], atol=ATOL)
    # A right triangle under y = x / 2 (no centre on its edge): the lattice spans its 0.4 x 0.2 box, and keeps
    # the centres below the slope.
    triangle = np.array([[0.0, 0.0], [0.4, 0.0], [0.4, 0.2]])
    below = polygon_lattice(triangle, 0.1)
    np.testing.assert_allclose(below, [[0.15, 0.05], [0.25, 0.05], [0.35, 0.05], [0.35, 0.15]], atol=ATOL)


def test_a_level_plane_is_rows_half_a_spacing_apart_under_its_surface():
    bounds = np.array([[0.0, 1.0], [0.0, 1.0]])
    layer = plane_layer(np.array([0.0, 0.5]), 0.0, bounds, spacing=0.1, layers=2)
    np.testing.assert_allclose(np.unique(layer[:, 1]), [0.35, 0.45], atol=ATOL)
    assert len(layer) == 20  # 10 particles across the 1 m domain per row
    assert inside(layer, bounds).all()


def test_an_inclined_plane_rises_at_its_angle():
    bounds = np.array([[0.0, 2.0], [0.0, 2.0]])
    layer = plane_layer(np.array([0.0, 0.5]), 30.0, bounds, spacing=0.05, layers=1)
    # One row: every particle half a spacing below the line y = 0.5 + x tan 30.
    depth = (0.5 + layer[:, 0] * np.tan(np.radians(30.0)) - layer[:, 1]) * np.cos(np.radians(30.0))
    np.testing.assert_allclose(depth, 0.025, atol=1e-9)
    assert inside(layer, bounds).all() and layer[:, 0].max() > 2.0 - 0.1


def test_a_3d_plane_repeats_its_rows_along_z():
    bounds = np.array([[0.0, 1.0], [0.0, 1.0], [0.0, 0.3]])
    layer = plane_layer(np.array([0.0, 0.5, 0.0]), 0.0, bounds, spacing=0.1, layers=1)
    np.testing.assert_allclose(np.unique(layer[:, 2]), [0.05, 0.15, 0.25], atol=ATOL)
    assert len(layer) == 10 * 3


@pytest.mark.parametrize("point, within", [([0.0, 0.5], True), ([1.0, 1.0], True), ([1.0 + 1e-9, 0.5], False)])
def test_inside_includes_the_walls(point, within):
    assert inside(np.array([point]), np.array([[0.0, 1.0], [0.0, 1.0]])).tolist() == [within]
