"""The material contract: particle types, whether prescribed, per-particle properties."""

from __future__ import annotations

from abc import ABC
from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class MaterialProperty:
    """A per-particle scalar a material contributes to node features."""

    name: str
    description: str
    unit: str = ""
    default: float = 0.0


PARTICLE_TYPE_IDS = range(0, 1024)
"""Valid particle-type ids: the model looks ids up in a table of (largest id + 1) rows
(``features.py``), so they are small non-negative ints. The public datasets use 0-8."""


class Material(ABC):
    """A particle material: its type id, whether it is prescribed, and its properties.

    Materials carry no code the model runs; they declare what a scene contains.
    """

    name: ClassVar[str]
    particle_type: ClassVar[int]
    kinematic: ClassVar[bool] = False
    """Prescribed: its particles follow given paths and are never predicted, nor counted in
    statistics, losses or error metrics."""
    granular: ClassVar[bool] = False
    """A granular material (sand, gravel): rollouts of it are also scored by runout and pile profile."""
    properties: ClassVar[tuple[MaterialProperty, ...]] = ()
    description: ClassVar[str] = ""
    constitutive_model: ClassVar[str | None] = None
    """How a ground-truth simulator moves this material (e.g. ``"drucker_prager"``,
    ``"weakly_compressible"``, ``"von_mises"``, ``"rigid"``); None: no
    simulator can generate it. Each simulator lists the models it supports."""
    physical_parameters: ClassVar[dict[str, float]] = {}
    """Default values (SI units) of the constitutive model's parameters, e.g.
    ``{"density": 1000.0, "bulk_modulus": 2e5}``; a scene's per-block
    ``properties`` override those named like a :class:`MaterialProperty`."""
