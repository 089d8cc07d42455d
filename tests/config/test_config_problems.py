"""pydantic's errors as ``(location, message)`` problems (``gns_framework.config.problems``): the location written
as the user writes it, an unknown key with a did-you-mean and the keys allowed where it stands, a missing key
said plainly, and the offending value quoted."""

from __future__ import annotations

from typing import Annotated, Any

import pytest
from pydantic import BaseModel, ConfigDict, Discriminator, Tag, ValidationError

from gns_framework.config.problems import format_location, problems_from


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Block(Strict):
    size: list[float]
    material: str = "sand"


class Box(Strict):
    width: float
    height: float = 1.0


class Disc(Strict):
    radius: float


def _shape_kind(value: Any) -> str:
    """The project's discriminated unions tag their members ``@name`` (as ``ground_truth.scene_spec`` does)."""
    return "@disc" if isinstance(value, dict) and "radius" in value else "@box"


Shape = Annotated[Annotated[Box, Tag("@box")] | Annotated[Disc, Tag("@disc")], Discriminator(_shape_kind)]


class Scene(Strict):
    name: str
    blocks: list[Block] = []
    shape: Shape | None = None
    frames: int = 10


def problems(raw: dict, prefix: tuple = ()) -> list[tuple[str, str]]:
    with pytest.raises(ValidationError) as caught:
        Scene.model_validate(raw)
    return problems_from(caught.value, Scene, prefix)


def test_locations_read_as_written_in_the_file():
    assert format_location(("blocks", 0, "size", 1)) == "blocks[0].size[1]"
    assert format_location(("shape", "@box", "width")) == "shape.width"  # a union's tag is not a key of the file
    assert format_location(("frames",)) == "frames"
    assert format_location(()) == ""


def test_an_unknown_key_gets_a_did_you_mean_and_the_keys_allowed_where_it_stands():
    found = problems({"name": "x", "blocks": [{"size": [1.0], "materail": "water"}], "frame": 3})
    assert sorted(found) == [
        ("blocks[0].materail", "unknown key (did you mean 'material'?); allowed: size, material"),
        ("frame", "unknown key (did you mean 'frames'?); allowed: name, blocks, shape, frames"),
    ]


def test_an_unknown_key_of_a_union_member_lists_that_members_keys():
    # The member's tag (@box) is in pydantic's location but not in the file: left out, and the key's owner found.
    assert problems({"name": "x", "shape": {"width": 1.0, "hight": 2.0}}) == [
        ("shape.hight", "unknown key (did you mean 'height'?); allowed: width, height")
    ]


def test_an_unknown_key_of_a_later_union_member_lists_that_members_keys_not_the_firsts():
    assert problems({"name": "x", "shape": {"radius": 1.0, "radios": 2.0}}) == [
        ("shape.radios", "unknown key (did you mean 'radius'?); allowed: radius")
    ]


def test_missing_keys_are_said_plainly_and_bad_values_are_quoted():
    found = dict(problems({"blocks": [{"size": ["wide"]}], "frames": "ten"}))
    assert found["name"] == "required key missing"
    assert (
        found["blocks[0].size[0]"] == "Input should be a valid number, unable to parse string as a number (got 'wide')"
    )
    assert found["frames"] == "Input should be a valid integer, unable to parse string as an integer (got 'ten')"


def test_a_value_where_a_mapping_belongs_is_not_quoted():
    # A number where a block (a mapping) belongs: the message names what is expected; the input, which for
    # the same error on a whole section could be any size, is not echoed.
    (problem,) = problems({"name": "x", "blocks": [3]})
    assert problem == ("blocks[0]", "Input should be a valid dictionary or instance of Block")


def test_a_prefix_places_the_problems_inside_a_larger_file():
    assert problems({"name": "x", "frames": "ten"}, prefix=("scenes", 2)) == [
        ("scenes[2].frames", "Input should be a valid integer, unable to parse string as an integer (got 'ten')")
    ]
