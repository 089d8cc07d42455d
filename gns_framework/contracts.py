"""Typed contracts of every component kind.

A component is a plain class with a registry ``name`` and a nested pydantic
``Params`` model (unknown keys are errors). Plugins return such classes from the
hooks in :mod:`gns_framework.hookspecs`; the core builds them with
``cls(params, ...)`` and calls them directly, never through pluggy.

Shapes: N particles (all examples of a batch stacked), E edges, d spatial
dimensions, C positions of history, L latent size, B examples.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal

from pydantic import BaseModel, ConfigDict
from torch import Tensor, nn

if TYPE_CHECKING:
    from .data.metadata import DatasetMetadata
    from .data.trajectory import Trajectory
    from .ground_truth.scene_spec import SceneSpec


class Params(BaseModel):
    """Base of every component's ``Params``: unknown keys are errors; a number where a string
    is expected is the text it was written as (see ``gns_framework.config.yaml_files``)."""

    model_config = ConfigDict(extra="forbid", coerce_numbers_to_str=True)


ComponentParams = Params
"""The same class under a second name, for a component's ``class Params(ComponentParams)``: inside a
class body that defines ``Params``, the name ``Params`` is the attribute being defined, and type
checkers read ``class Params(Params)`` as a cyclic definition."""


@dataclass(frozen=True)
class Graph:
    """Directed connectivity of one batch of particles.

    Attributes:
        senders: (E,) int64 index of the particle each edge comes from.
        receivers: (E,) int64 index of the particle each edge points to (messages
            are summed at receivers). Built-in builders sort edges by
            (receiver, sender).
        displacement: (E, d) float, ``p_sender - p_receiver`` in dataset units
            (minimum image in periodic domains).
        num_nodes: N.
        position: (N, d) float, each particle's current position in dataset units, for
            processors that work on space itself (a grid) rather than on edges; the
            learned simulator attaches it, builders need not (None: not given).
        batch: (N,) int64 example index of each particle (non-decreasing), or None
            (one example), so such processors keep the examples of a batch apart.
        num_examples: B.
    """

    senders: Tensor
    receivers: Tensor
    displacement: Tensor
    num_nodes: int
    position: Tensor | None = None
    batch: Tensor | None = None
    num_examples: int = 1

    @property
    def num_edges(self) -> int:
        return int(self.senders.shape[0])


@dataclass(frozen=True)
class MaterialProperty:
    """A per-particle scalar a material contributes to node features."""

    name: str
    description: str
    unit: str = ""
    default: float = 0.0


@dataclass(frozen=True)
class Scene:
    """What a learned model must know of the scenes it simulates; its sizes follow from it.

    Derived from the training data (:mod:`gns_framework.assembly.scene`) and stored in
    every checkpoint. A scene *file* (``scenes/*.yaml``, read into
    :class:`gns_framework.ground_truth.scene_spec.SceneSpec`) is what the ground-truth
    simulator runs; this is the learned model's summary of the scenes in its data.

    Attributes:
        dim: spatial dimensions d (2 or 3).
        bounds: (d, 2) lower and upper walls, dataset units.
        connectivity_radius: R; particles closer than R (strict) are connected.
        particle_types: sorted type ids the model handles (one per material).
        kinematic_types: the subset of ``particle_types`` that is prescribed.
        property_names: per-particle material properties, in node-feature column order.
        context_size: width of the per-frame global context (0: none).
        history: C, positions per input window (C - 1 velocities).
        walls: whether wall-distance features are built (for the non-periodic dimensions).
        boundary_clamp_limit: wall distances / R are clipped to +-this.
        periodic: per dimension, whether the domain wraps around there (minimum-image
            displacements, no walls); empty means no periodic dimension.
        wall_conditions: whether each walled face's Coulomb friction coefficient is a node
            feature (from the data's per-trajectory ``walls``), so one model learns rough
            and slip walls.
    """

    dim: int
    bounds: tuple[tuple[float, float], ...]
    connectivity_radius: float
    particle_types: tuple[int, ...]
    kinematic_types: tuple[int, ...] = ()
    property_names: tuple[str, ...] = ()
    context_size: int = 0
    history: int = 6
    walls: bool = True
    boundary_clamp_limit: float = 1.0
    periodic: tuple[bool, ...] = ()
    wall_conditions: bool = False

    @property
    def num_particle_types(self) -> int:
        return len(self.particle_types)

    @property
    def uses_type_embedding(self) -> bool:
        return len(self.particle_types) > 1

    @property
    def periodic_dims(self) -> tuple[int, ...]:
        """Indices of the dimensions that wrap around."""
        return tuple(k for k, wraps in enumerate(self.periodic) if wraps)

    @property
    def wall_dims(self) -> tuple[int, ...]:
        """Indices of the dimensions bounded by walls (none when ``walls`` is False)."""
        if not self.walls:
            return ()
        return tuple(k for k in range(self.dim) if k not in self.periodic_dims)


@dataclass(frozen=True)
class ModelSizes:
    """Sizes shared by encoder, processor and decoder, derived from the scene and recipe."""

    node_in: int
    edge_in: int
    latent: int
    mlp_hidden: int
    mlp_hidden_layers: int
    output: int
    dim: int
    connectivity_radius: float = 1.0
    """R, the length unit of ``Graph.displacement`` for processors that use geometry."""


class GraphBuilder(ABC):
    """Finds the edges of a batch of particles."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    supports_periodic: ClassVar[bool] = False
    optional_modules: ClassVar[tuple[str, ...]] = ()
    """Importable modules this component needs beyond the project's own requirements (``gns check`` finds the
    missing ones); any component class may declare it."""
    """Whether it connects particles across periodic boundaries (minimum image)."""

    def __init__(self, params: ComponentParams, scene: Scene):
        self.params = params
        self.scene = scene

    @abstractmethod
    def build(self, position: Tensor, batch: Tensor, num_examples: int) -> Graph:
        """Connect particles of the same example.

        Args:
            position: (N, d) current positions.
            batch: (N,) int64 example index of every particle, non-decreasing.
            num_examples: B.
        """


class Encoder(nn.Module, ABC):
    """Maps node and edge features to latents."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_features: Tensor, edge_features: Tensor) -> tuple[Tensor, Tensor]:
        """(N, node_in), (E, edge_in) -> node latent (N, L), edge latent (E, L)."""


class Processor(nn.Module, ABC):
    """Message passing on the latent graph."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_latent: Tensor, edge_latent: Tensor, graph: Graph) -> tuple[Tensor, Tensor]:
        """(N, L), (E, L) -> updated (N, L), (E, L)."""


class Decoder(nn.Module, ABC):
    """Maps node latents to the normalised quantity the integrator consumes."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params

    def __init__(self, params: ComponentParams, sizes: ModelSizes):
        super().__init__()
        self.params = params

    @abstractmethod
    def forward(self, node_latent: Tensor) -> Tensor:
        """(N, L) -> (N, sizes.output)."""


class Integrator(ABC):
    """Turns the model's (de-normalised) prediction into the next position, and back.

    Time is in frames (dt = 1): velocities and accelerations are finite
    differences of positions, as in the reference model. ``predicts`` says which
    statistics normalise the decoder's output.

    Integrators that model a second-order ODE may also offer the physical form
    ``advance(position, velocity, acceleration_fn, dt) -> (position, velocity)``
    (one step of ``dx/dt = v, dv/dt = acceleration_fn(x)``), for use with a force
    law instead of a learned model (stability studies, ground-truth generation).
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    predicts: ClassVar[Literal["acceleration", "velocity"]] = "acceleration"
    symplectic: ClassVar[bool] = False
    """Whether ``advance`` is symplectic: below its stability bound the energy stays bounded, with no drift."""
    stability_bound: ClassVar[float | None] = None
    """Largest ``omega dt`` for which ``advance`` is stable on the harmonic oscillator
    ``a = -omega^2 x`` (2 for symplectic Euler and velocity Verlet); 0 when no step is
    stable (explicit Euler); None without a physical form. ``gns stability`` checks it."""

    def __init__(self, params: ComponentParams):
        self.params = params

    @abstractmethod
    def next_position(self, position_sequence: Tensor, prediction: Tensor) -> Tensor:
        """(N, C, d) history and (N, d) prediction -> (N, d) next position."""

    @abstractmethod
    def target(self, position_sequence: Tensor, next_position: Tensor) -> Tensor:
        """Exact inverse of :meth:`next_position`: the prediction that reaches ``next_position``."""


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


class Dataset(ABC):
    """A dataset layout on disk: metadata plus train/valid/test splits of trajectories."""

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    writable: ClassVar[bool] = False

    def __init__(self, params: ComponentParams, path: Path, allow_pickle: bool = False):
        """``allow_pickle``: the user's grant to unpickle anything from the files under ``path``.

        It comes from one command's ``--allow-pickle FOLDER`` for this folder,
        never from a recipe or a checkpoint, which can travel to other data.
        Layouts that store pickles read them without it only where they can do so
        without running code from the file.
        """
        self.params = params
        self.path = Path(path)
        self.allow_pickle = allow_pickle

    @abstractmethod
    def metadata(self) -> "DatasetMetadata":
        """The validated metadata of this dataset."""

    @abstractmethod
    def split(self, name: str) -> Sequence["Trajectory"]:
        """Trajectories of a split (``train``, ``valid``, ``test``), loaded lazily and validated."""

    def splits(self) -> list[str]:
        """Names of the splits present on disk."""
        return [s for s in ("train", "valid", "test") if self.has_split(s)]

    def has_split(self, name: str) -> bool:
        return False

    @classmethod
    def write(
        cls, path: Path, metadata: "DatasetMetadata", splits: Mapping[str, Sequence["Trajectory"]]
    ) -> None:
        """Write ``metadata`` and ``splits`` in this layout (only when ``writable``)."""
        raise NotImplementedError(f"dataset layout {cls.name!r} is read-only")


class GroundTruthSimulator(ABC):
    """A particle solver that generates ground-truth trajectories from a scene spec.

    The default is MLS-MPM; a user's own solver (or a converter of its output
    files) plugs in the same way and feeds ``gns generate``.
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]] = Params
    dims: ClassVar[tuple[int, ...]] = (2, 3)
    constitutive_models: ClassVar[tuple[str, ...]] = ()
    """The :attr:`Material.constitutive_model` values this simulator can move."""

    def __init__(self, params: ComponentParams, materials: dict[str, type[Material]]):
        self.params = params
        self.materials = materials

    def check(self, scene: "SceneSpec") -> list[tuple[str, str]]:
        """Problems (location, message) of this simulator's own that stop it from running ``scene``.

        Stability limits (time step versus wave speed) and the like. The checks every
        simulator shares (dimension, materials and their constitutive models,
        obstacles, properties) are made before, by
        :func:`gns_framework.ground_truth.scene_checks.scene_problems`; none here by default.
        """
        return []

    @abstractmethod
    def simulate(self, scene: "SceneSpec", seed: int) -> "Trajectory":
        """Run ``scene`` with randomness drawn from ``seed``; the same seed gives the same bits.

        Returns a trajectory of ``scene.time.frames`` frames: position (T, N, d)
        float32 inside the scene's bounds, particle_type (N,), material_property
        (N, P) only when the scene sets properties.
        """


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
