"""A scene's values: numbers become ranges of width 0, ranges are ordered, choices weigh their options."""

from __future__ import annotations

import pytest
from pydantic import TypeAdapter, ValidationError

from gns_framework.ground_truth.scene_values import Count, OneOf, Range, Span, Value, is_spanned

VALUE = TypeAdapter(Value)


def test_a_number_is_a_fixed_range_and_a_count_a_range_of_bodies():
    assert VALUE.validate_python(0.25) == Range(range=(0.25, 0.25))
    assert VALUE.validate_python(0.25).is_fixed
    assert TypeAdapter(Count).validate_python(3) == Range(range=(3, 3))


def test_each_form_of_value():
    assert isinstance(VALUE.validate_python({"range": [0.1, 0.2], "per": "particle"}), Range)
    assert isinstance(VALUE.validate_python({"span": [0.0, 1.0]}), Span)
    choice = VALUE.validate_python({"one_of": [0.1, {"range": [0.3, 0.4]}], "weights": [1, 3]})
    assert isinstance(choice, OneOf) and (choice.low, choice.high) == (0.1, 0.4) and not choice.is_fixed


def test_spans_are_positions_relative_to_the_domain():
    assert is_spanned(VALUE.validate_python({"span": [0.0, 1.0]}))
    assert is_spanned(VALUE.validate_python({"one_of": [0.1, {"span": [0.2, 0.3]}]}))
    assert not is_spanned(VALUE.validate_python(0.1))


@pytest.mark.parametrize(
    "raw, message",
    [
        ({"range": [0.4, 0.2]}, "low <= high"),
        ({"one_of": [0.1, 0.2], "weights": [1]}, "weights"),
        ({"rnage": [0.1, 0.2]}, ""),
    ],
)
def test_malformed_values_are_refused(raw, message):
    with pytest.raises(ValidationError, match=message):
        VALUE.validate_python(raw)
