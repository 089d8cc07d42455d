"""The values of a scene spec: numbers, random ranges, spans of free room, choices, and counts of bodies.

Any number in a block or obstacle may be ``{range: [low, high]}`` drawn once per
trajectory (``per: particle``: one value per particle), ``{one_of: [...]}`` picks an
option per trajectory, and a position along an axis may be ``{span: [low, high]}``,
a fraction of the room the body leaves free there (scene_spec.py says more).
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    model_validator,
)


class Spec(BaseModel):
    """Base of every scene-spec section: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True, coerce_numbers_to_str=True)


class _Interval(Spec):
    """An interval ``[low, high]`` held in the field named by ``_bounds``."""

    _bounds: ClassVar[str]

    @property
    def low(self) -> float:
        return getattr(self, self._bounds)[0]

    @property
    def high(self) -> float:
        return getattr(self, self._bounds)[1]

    @property
    def is_fixed(self) -> bool:
        return self.low == self.high


class Range(_Interval):
    """A value drawn uniformly from ``[low, high]``; a plain number is a range of width 0."""

    _bounds: ClassVar[str] = "range"
    range: tuple[float, float]
    per: Literal["trajectory", "particle"] = "trajectory"

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        if self.range[0] > self.range[1]:
            raise ValueError(f"range must be [low, high] with low <= high, got {list(self.range)}")
        return self


class Span(_Interval):
    """A position along one axis as a fraction of the room a body leaves free there.

    The body's lower corner is ``lower wall + u * (domain extent - body size)`` with
    ``u`` drawn from ``[low, high]`` within [0, 1]: 0 puts it against the lower wall,
    1 against the upper one. Only positions take spans.
    """

    _bounds: ClassVar[str] = "span"
    span: tuple[float, float]

    @model_validator(mode="before")
    @classmethod
    def _scalar(cls, data: Any) -> Any:
        if isinstance(data, dict) and isinstance(data.get("span"), (int, float)) and not isinstance(data["span"], bool):
            return {**data, "span": (data["span"], data["span"])}
        return data

    @model_validator(mode="after")
    def _fraction(self) -> Span:
        if not 0.0 <= self.span[0] <= self.span[1] <= 1.0:
            raise ValueError(f"span must be [low, high] with 0 <= low <= high <= 1, got {list(self.span)}")
        return self

    per: Literal["trajectory"] = "trajectory"


def _number_or_range(value: Any) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"expected a number, {{range: [low, high]}} or {{span: [low, high]}}, got {value!r}")
    if isinstance(value, (int, float)):
        return {"range": (value, value)}
    if isinstance(value, (dict, Range, Span)):
        return value
    raise ValueError(f"expected a number, {{range: [low, high]}} or {{span: [low, high]}}, got {value!r}")


def _single_kind(value: Any) -> str:
    """Which of Range and Span a mapping is (by its key), so errors speak of that one only.

    Tags start with ``@``, which problem locations leave out (:mod:`gns_framework.config.problems`).
    """
    if isinstance(value, Span) or (isinstance(value, dict) and "span" in value):
        return "@span"
    return "@range"


Single = Annotated[
    Annotated[Range, Tag("@range")] | Annotated[Span, Tag("@span")],
    Discriminator(_single_kind),
    BeforeValidator(_number_or_range),
]
"""A number, ``{range: [low, high], per: trajectory|particle}`` or ``{span: [low, high]}``."""


class Weighted(Spec):
    """A pick among the options of ``one_of`` (a subclass's field), ``weights`` their probabilities (None:
    equal), normalised: one per option, >= 0, with a positive sum."""

    weights: list[float] | None = None

    @model_validator(mode="after")
    def _weights(self) -> Weighted:
        options = len(getattr(self, "one_of"))  # noqa: B009 (declared by each subclass, with its own option type)
        if self.weights is None:
            return self
        if len(self.weights) != options:
            raise ValueError(f"weights: expected {options} values (one per option), got {len(self.weights)}")
        if min(self.weights) < 0 or sum(self.weights) <= 0:
            raise ValueError(f"weights must be >= 0 with a positive sum, got {self.weights}")
        return self


class OneOf(Weighted):
    """One of several options (numbers, ranges or spans), picked per trajectory, then drawn."""

    one_of: list[Single] = Field(min_length=1)
    per: Literal["trajectory"] = "trajectory"

    @property
    def low(self) -> float:
        return min(option.low for option in self.one_of)

    @property
    def high(self) -> float:
        return max(option.high for option in self.one_of)

    @property
    def is_fixed(self) -> bool:
        return len(self.one_of) == 1 and self.one_of[0].is_fixed

    @property
    def has_span(self) -> bool:
        return any(isinstance(option, Span) for option in self.one_of)


def _value_kind(value: Any) -> str:
    if isinstance(value, OneOf) or (isinstance(value, dict) and "one_of" in value):
        return "@one_of"
    return _single_kind(value)


Value = Annotated[
    Annotated[Range, Tag("@range")] | Annotated[Span, Tag("@span")] | Annotated[OneOf, Tag("@one_of")],
    Discriminator(_value_kind),
    BeforeValidator(_number_or_range),
]
"""A number, ``{range: [low, high], per: trajectory|particle}``, ``{span: [low, high]}`` (positions)
or ``{one_of: [option, ...], weights: [...]}``."""


def is_spanned(value: Range | Span | OneOf) -> bool:
    """Whether a value is (or may pick) a span, a position relative to the domain."""
    return isinstance(value, Span) or (isinstance(value, OneOf) and value.has_span)


def _number_of_bodies(value: Any) -> Any:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return {"range": (value, value)}
    return value


Count = Annotated[Range, BeforeValidator(_number_of_bodies)]
"""A whole number of bodies, or ``{range: [low, high]}`` of whole numbers drawn per trajectory."""
