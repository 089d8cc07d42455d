"""Small scene mappings for tests: coarse grids and few frames, so each runs in about a second."""

from __future__ import annotations

import pytest

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.errors import RecipeError
from gns_framework.ground_truth.scene_spec import parse_scene


def column_collapse(width: float, height: float, friction: float, frames: int = 240) -> dict:
    """A 2D sand column of ``width`` x ``height`` m against the left wall (dx = 12.5 mm)."""
    return {
        "name": "test_column",
        "dim": 2,
        "domain": {"bounds": [[0.0, 0.8], [0.0, 0.4]], "grid": 64, "wall_friction": 0.5},
        "time": {"frame_dt": 0.0025, "substeps": 10, "frames": frames},
        "blocks": [
            {
                "material": "sand",
                "position": [0.0, 0.0],
                "size": [width, height],
                "parameters": {"friction": friction},
            }
        ],
    }


def column_collapse_3d(frames: int = 100) -> dict:
    """A square sand column, 768 particles, in the middle of a coarse 3D box (dx = 25 mm), y up."""
    return {
        "name": "test_column_3d",
        "dim": 3,
        "domain": {"bounds": [[0.0, 0.6], [0.0, 0.3], [0.0, 0.6]], "grid": 24},
        "time": {"frame_dt": 0.0025, "substeps": 5, "frames": frames},
        "blocks": [{"material": "sand", "position": [0.25, 0.0, 0.25], "size": [0.1, 0.15, 0.1]}],
    }


def dam_break(width: float, height: float, frames: int = 140) -> dict:
    """A water column of ``width`` x ``height`` m against the left wall of a frictionless tank."""
    return {
        "name": "test_dam_break",
        "dim": 2,
        "domain": {"bounds": [[0.0, 1.0], [0.0, 0.5]], "grid": 80, "wall_friction": 0.0},
        "time": {"frame_dt": 0.0025, "substeps": 12, "frames": frames},
        "blocks": [{"material": "water", "position": [0.0, 0.0], "size": [width, height]}],
    }


def mixed(frames: int = 40) -> dict:
    """Every material, random ranges, a per-particle property and a moving obstacle."""
    return {
        "name": "test_mixed",
        "dim": 2,
        "domain": {"bounds": [[0.0, 0.5], [0.0, 0.5]], "grid": 32},
        "time": {"frame_dt": 0.0025, "substeps": 8, "frames": frames},
        "blocks": [
            {"material": "water", "position": [0.02, 0.0], "size": [0.1, {"range": [0.1, 0.15]}]},
            {
                "material": "sand",
                "position": [{"range": [0.2, 0.25]}, 0.1],
                "size": [0.08, 0.08],
                "properties": {"friction": {"range": [0.5, 0.9], "per": "particle"}},
            },
            {
                "material": "goop",
                "shape": "ellipsoid",
                "position": [0.35, 0.2],
                "size": [0.1, 0.1],
                "velocity": [{"range": [-0.5, 0.0]}, 0.0],
            },
        ],
        "obstacles": [{"material": "rigid", "position": [0.2, 0.02], "size": [0.1, 0.04], "velocity": [0.2, 0.0]}],
    }


def problems(raw, registry=None) -> dict[str, str]:
    """The ``location -> message`` problems a scene mapping is refused with (the test fails if it is accepted)."""
    with pytest.raises(RecipeError) as info:
        scene = parse_scene(raw)
        build_ground_truth_simulator(scene, registry)
    return dict(info.value.problems)
