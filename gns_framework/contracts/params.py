"""The base of every component's ``Params``: strict pydantic models, unknown keys are errors."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Params(BaseModel):
    """Base of every component's ``Params``: unknown keys are errors; a number where a string
    is expected is the text it was written as (see ``gns_framework.config.yaml_files``)."""

    model_config = ConfigDict(extra="forbid", coerce_numbers_to_str=True)


ComponentParams = Params
"""The same class under a second name, for a component's ``class Params(ComponentParams)``: inside a
class body that defines ``Params``, the name ``Params`` is the attribute being defined, and type
checkers read ``class Params(Params)`` as a cyclic definition."""
