"""What a plugin (a built-in one too) uses of the framework besides its contracts, in one place.

A component implements a contract of :mod:`gns_framework.contracts` and registers it
with :data:`hookimpl`; what it may call on the way is here. Names outside these two
modules are the framework's own and may move between releases; these do not move
without a deprecation warning. Grouped by what a plugin does with them.
"""

from __future__ import annotations

# Reading and writing datasets: records, metadata, lazily read trajectories, checks, limits on input.
from .data.atomic import atomic_path, write_text_atomic
from .data.consistency import checked
from .data.lazy import TrajectorySequence
from .data.metadata import DatasetMetadata, load_metadata, parse_metadata, read_metadata_json
from .data.npz_mapping import mapped_member
from .data.particle_spacing import particle_spacing
from .data.trajectory import Trajectory

# Registering components and naming what went wrong.
from .errors import DatasetError, GnsError, PluginError, RecipeError

# Metrics of rollouts.
from .evaluation.free_deposit import free_deposits
from .evaluation.metrics import RolloutPair, horizon_mse, per_material_mse

# Ground-truth simulators: the scene file, sampled.
from .ground_truth.sampling import BodySample, SceneSample, at_resolution, sample_scene
from .ground_truth.scene_spec import SceneSpec
from .hookspecs import hookimpl

# Building blocks of learned components.
from .layers import MLP, NormedMLP
from .limits import (
    INFLATE_RATIO_ABOVE,
    MAX_INFLATE_RATIO,
    LimitError,
    check_array_header,
    check_memory,
    check_record_length,
    check_zip_member,
)
from .model.periodic import PeriodicBox
from .plugin_types import Command, Metric

# Devices, and the choices the accelerators' code paths make (kernels).
from .runtime.activation_memory import recompute_activations
from .runtime.deterministic import deterministic_sums
from .runtime.device import choose_device
from .runtime.host_sync import PerDevice, avoids_read_backs, read_back
from .specs import ComponentSpec

__all__ = [
    "INFLATE_RATIO_ABOVE",
    "MAX_INFLATE_RATIO",
    "MLP",
    "BodySample",
    "Command",
    "ComponentSpec",
    "DatasetError",
    "DatasetMetadata",
    "GnsError",
    "LimitError",
    "Metric",
    "NormedMLP",
    "PerDevice",
    "PeriodicBox",
    "PluginError",
    "RecipeError",
    "RolloutPair",
    "SceneSample",
    "SceneSpec",
    "Trajectory",
    "TrajectorySequence",
    "at_resolution",
    "atomic_path",
    "avoids_read_backs",
    "check_array_header",
    "check_memory",
    "check_record_length",
    "check_zip_member",
    "checked",
    "choose_device",
    "deterministic_sums",
    "free_deposits",
    "hookimpl",
    "horizon_mse",
    "load_metadata",
    "mapped_member",
    "parse_metadata",
    "particle_spacing",
    "per_material_mse",
    "read_back",
    "read_metadata_json",
    "recompute_activations",
    "sample_scene",
    "write_text_atomic",
]
