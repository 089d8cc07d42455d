"""Typed contracts of every component kind.

A component is a plain class with a registry ``name`` and a nested pydantic
``Params`` model (unknown keys are errors). Plugins return such classes from the
hooks in :mod:`gns_framework.hookspecs`; the core builds them with
``cls(params, ...)`` and calls them directly, never through pluggy.

Shapes: N particles (all examples of a batch stacked), E edges, d spatial
dimensions, C positions of history, L latent size, B examples.
"""

from __future__ import annotations

import warnings

from .dataset import Dataset
from .decoder import Decoder
from .encoder import Encoder
from .graph import Graph
from .graph_builder import GraphBuilder
from .integrator import Integrator
from .learned_part import LearnedPart
from .material import PARTICLE_TYPE_IDS, Material, MaterialProperty
from .params import ComponentParams, Params
from .processor import Processor
from .setup import ModelSetup, ModelSizes
from .simulator import GroundTruthSimulator

__all__ = [
    "COMPONENT_KINDS",
    "PARTICLE_TYPE_IDS",
    "ComponentParams",
    "Dataset",
    "Decoder",
    "Encoder",
    "Graph",
    "GraphBuilder",
    "GroundTruthSimulator",
    "Integrator",
    "LearnedPart",
    "Material",
    "MaterialProperty",
    "ModelSetup",
    "ModelSizes",
    "Params",
    "Processor",
]

COMPONENT_KINDS: dict[str, type] = {
    "graph_builder": GraphBuilder,
    "encoder": Encoder,
    "processor": Processor,
    "decoder": Decoder,
    "integrator": Integrator,
    "dataset": Dataset,
    "material": Material,
    "simulator": GroundTruthSimulator,
}
"""Every component kind, by its recipe key, with its contract."""


def __getattr__(name: str) -> type[ModelSetup]:
    # Plugins written against 0.1 import the model's setup as ``Scene``: one release of grace.
    if name == "Scene":
        warnings.warn(
            "gns_framework.contracts.Scene is now ModelSetup (the learned model's setup; a scene file is a "
            "SceneSpec); the old name goes in 0.3",
            DeprecationWarning,
            stacklevel=2,
        )
        return ModelSetup
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
