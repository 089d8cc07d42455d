"""The space helpers slabs and blocks share (``gns_framework.decomposition.space``)."""

from __future__ import annotations

import pytest
import torch

from gns_framework.decomposition.space import CutOptions, check_parts, distance_to_interval, periodic_boxes


def test_only_the_periodic_dimensions_get_their_box():
    bounds = ((0.0, 1.0), (-2.0, 3.0), (5.0, 6.0))
    assert periodic_boxes(3, CutOptions(periodic_dims=(1,), bounds=bounds)) == [None, (-2.0, 3.0), None]
    assert periodic_boxes(2, CutOptions()) == [None, None]
    with pytest.raises(AssertionError, match="needs the box bounds"):
        periodic_boxes(2, CutOptions(periodic_dims=(0,)))


def test_parts_start_at_one():
    check_parts(1)
    with pytest.raises(ValueError, match="at least 1, got 0"):
        check_parts(0)


def test_distance_is_zero_inside_and_the_gap_outside_in_both_shapes():
    x = torch.tensor([[-1.0], [0.5], [3.0]], dtype=torch.float64)
    lower = torch.tensor([0.0, 2.0], dtype=torch.float64)
    upper = torch.tensor([1.0, 2.5], dtype=torch.float64)
    assert distance_to_interval(x, lower, upper).tolist() == [[1.0, 3.0], [0.0, 1.5], [2.0, 0.5]]
    points = torch.tensor([[[0.5, 4.0]]], dtype=torch.float64)  # (1, 1, d)
    boxes_lower = torch.tensor([[0.0, 0.0]], dtype=torch.float64)
    boxes_upper = torch.tensor([[1.0, 1.0]], dtype=torch.float64)
    assert distance_to_interval(points, boxes_lower, boxes_upper).tolist() == [[[0.0, 3.0]]]
