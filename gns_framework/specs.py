"""How recipes and scene specs name a component: its registered ``name`` plus that component's parameters.

This module imports nothing else from gns-framework, so recipes, scene specs and
the registry can all depend on it without depending on each other.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict


class ComponentSpec(BaseModel):
    """``name`` of a registered component plus its parameters."""

    # A number where a string is expected is that string (``name: 1e5``, see config.yaml_files).
    model_config = ConfigDict(extra="allow", coerce_numbers_to_str=True)
    name: str

    @property
    def params(self) -> dict[str, Any]:
        return dict(self.model_extra or {})
