"""A scene's domain: wall conditions by face, drawn or fixed, and time stepping."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gns_framework.ground_truth.scene_domain import FACES, Time, WallChoice, WallRange, Walls


def test_faces_take_a_condition_a_friction_range_or_a_choice():
    walls = Walls.model_validate(
        {"x_min": "slip", "x_max": 0.4, "y_min": {"range": [0.3, 0.6]}, "y_max": {"one_of": ["no_slip", 0.2]}}
    )
    assert walls.x_min == "slip" and walls.x_max == 0.4
    assert isinstance(walls.y_min, WallRange) and isinstance(walls.y_max, WallChoice)
    assert walls.is_drawn and not Walls.model_validate({"x_min": "slip"}).is_drawn
    assert FACES[:2] == ("x_min", "x_max")


@pytest.mark.parametrize("condition", [-0.1, "sticky"])
def test_a_face_condition_is_a_friction_slip_or_no_slip(condition):
    with pytest.raises(ValidationError, match="friction coefficient"):
        Walls.model_validate({"x_min": condition})


def test_time_steps():
    time = Time(frame_dt=0.01, substeps=20, frames=50)
    assert time.substep_dt == pytest.approx(5e-4)
    with pytest.raises(ValidationError):
        Time(frame_dt=0.01, substeps=0, frames=50)
