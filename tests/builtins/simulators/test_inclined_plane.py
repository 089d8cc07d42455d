"""Friction of an inclined plane (issue 19): a sand block holds below atan(mu) and slides above it.

The scene and measurement are benchmarks/inclined_plane.py's, which scans the
angle and finds the threshold within ~1 degree of atan(mu) (docs/ground_truth.md).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from load_script import load_script

SCRIPT = Path(__file__).resolve().parents[3] / "benchmarks" / "inclined_plane.py"


@pytest.fixture(scope="module")
def inclined_plane():
    return load_script(SCRIPT)


MU = 0.5
THRESHOLD = math.degrees(math.atan(MU))  # 26.57 degrees


def test_block_holds_on_a_plane_3_degrees_shallower_than_atan_mu(inclined_plane, sim_registry):
    assert inclined_plane.sliding_speed(THRESHOLD - 3, MU, sim_registry) < inclined_plane.SLIDING_SPEED


def test_block_slides_like_a_rigid_block_on_a_plane_3_degrees_steeper(inclined_plane, sim_registry):
    """Above the threshold the block slides at the rigid block's speed g (sin - mu cos) t, within 25 %."""
    angle = THRESHOLD + 3
    speed = inclined_plane.sliding_speed(angle, MU, sim_registry)
    rigid = inclined_plane.rigid_block_speed(angle, MU)
    assert speed > inclined_plane.SLIDING_SPEED
    assert 0.75 * rigid < speed < 1.25 * rigid
