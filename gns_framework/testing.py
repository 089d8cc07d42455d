"""Conformance checks a plugin author runs on their component, from their own tests.

Each ``check_*`` function builds the component on small random inputs and raises
``AssertionError`` naming the broken property; it returns nothing when the
component conforms. Example (pytest)::

    from gns_framework.testing import check_processor

    def test_my_processor_conforms():
        check_processor(MyProcessor)

The checks use explicit raises, not ``assert``, so they also hold under ``python -O``.
"""

from __future__ import annotations

import inspect
import math
import tempfile
from collections.abc import Collection, Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from .contracts import (
    PARTICLE_TYPE_IDS,
    Dataset,
    Decoder,
    Encoder,
    Graph,
    GraphBuilder,
    GroundTruthSimulator,
    Integrator,
    Material,
    MaterialProperty,
    ModelSetup,
    ModelSizes,
    Processor,
)
from .model.periodic import PeriodicBox
from .moved import renamed_keywords

if TYPE_CHECKING:
    from .data.trajectory import Trajectory
    from .ground_truth.scene_spec import SceneSpec

__all__ = [
    "check_dataset",
    "check_decoder",
    "check_encoder",
    "check_graph_builder",
    "check_integrator",
    "check_material",
    "check_processor",
    "check_simulator",
    "small_scene",
    "small_sizes",
]


def _expect(condition: object, message: str) -> None:
    if not condition:
        raise AssertionError(message)


def _close(a: Tensor, b: Tensor, atol: float, rtol: float = 1e-4) -> bool:
    return a.shape == b.shape and bool(torch.allclose(a, b, atol=atol, rtol=rtol))


def small_sizes(dim: int = 2, latent: int = 16, connectivity_radius: float = 0.1) -> ModelSizes:
    """Sizes of a tiny model (for fast checks)."""
    return ModelSizes(
        node_in=(6 - 1) * dim + 2 * dim,
        edge_in=dim + 1,
        latent=latent,
        mlp_hidden=latent,
        mlp_hidden_layers=2,
        output=dim,
        dim=dim,
        connectivity_radius=connectivity_radius,
    )


def small_scene(dim: int = 2, connectivity_radius: float = 0.1, periodic: tuple[bool, ...] = ()) -> ModelSetup:
    """A unit-box scene with one material."""
    return ModelSetup(
        dim=dim,
        bounds=tuple((0.0, 1.0) for _ in range(dim)),
        connectivity_radius=connectivity_radius,
        particle_types=(5,),
        periodic=periodic,
    )


def _random_graph(num_nodes: int, dim: int, generator: torch.Generator) -> Graph:
    """A random directed graph with self-edges, sorted by (receiver, sender), and displacements."""
    position = torch.rand(num_nodes, dim, generator=generator)
    adjacency = torch.rand(num_nodes, num_nodes, generator=generator) < 0.3
    adjacency |= torch.eye(num_nodes, dtype=torch.bool)
    receivers, senders = adjacency.nonzero(as_tuple=True)
    batch = torch.zeros(num_nodes, dtype=torch.long)
    return Graph(senders, receivers, position[senders] - position[receivers], num_nodes, position, batch, 1)


def _permuted_graph(graph: Graph, perm: Tensor) -> tuple[Graph, Tensor]:
    """The graph with node ``perm[k]`` renamed k, edges re-sorted; also the new edge order."""
    inverse = torch.empty_like(perm)
    inverse[perm] = torch.arange(perm.numel())
    senders, receivers = inverse[graph.senders], inverse[graph.receivers]
    order = torch.argsort(receivers * graph.num_nodes + senders)
    position = None if graph.position is None else graph.position[perm]
    batch = None if graph.batch is None else graph.batch[perm]
    permuted = Graph(
        senders[order],
        receivers[order],
        graph.displacement[order],
        graph.num_nodes,
        position,
        batch,
        graph.num_examples,
    )
    return permuted, order


def check_processor(
    cls: type[Processor], params: Mapping | None = None, sizes: ModelSizes | None = None, seed: int = 0
) -> None:
    """Shapes, finite outputs, permutation equivariance and gradient flow of a processor.

    Permutation equivariance: renaming the nodes (and reordering the edges) renames
    the outputs the same way. Gradient flow: every parameter gets a gradient from the
    node latents alone, as in training, where the decoder reads nodes only.
    """
    _expect(inspect.isclass(cls) and issubclass(cls, Processor), f"{cls!r} is not a Processor subclass")
    sizes = sizes or small_sizes()
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    processor = cls(cls.Params.model_validate(dict(params or {})), sizes).double()
    graph = _random_graph(12, sizes.dim, generator)
    # In dataset units, as builders give them: displacements and positions of order R.
    radius = sizes.connectivity_radius
    assert graph.position is not None  # _random_graph gives it
    graph = replace(graph, displacement=graph.displacement.double() * radius, position=graph.position.double() * radius)
    x = torch.randn(graph.num_nodes, sizes.latent, generator=generator, dtype=torch.float64, requires_grad=True)
    e = torch.randn(graph.num_edges, sizes.latent, generator=generator, dtype=torch.float64, requires_grad=True)
    x_out, e_out = processor(x, e, graph)
    _expect(x_out.shape == x.shape, f"{cls.name}: node latent shape {tuple(x_out.shape)}, expected {tuple(x.shape)}")
    _expect(e_out.shape == e.shape, f"{cls.name}: edge latent shape {tuple(e_out.shape)}, expected {tuple(e.shape)}")
    _expect(bool(torch.isfinite(x_out).all() and torch.isfinite(e_out).all()), f"{cls.name}: non-finite outputs")

    perm = torch.randperm(graph.num_nodes, generator=generator)
    permuted, edge_order = _permuted_graph(graph, perm)
    x_perm, e_perm = processor(x[perm], e[edge_order], permuted)
    _expect(_close(x_perm, x_out[perm], 1e-9), f"{cls.name}: node outputs are not permutation-equivariant")
    _expect(_close(e_perm, e_out[edge_order], 1e-9), f"{cls.name}: edge outputs do not follow the edge reordering")

    # The decoder reads the node latents alone, so the gradient flows back from them only: a parameter that
    # only the returned edge latents depend on never trains, and DistributedDataParallel refuses it.
    x_out.square().sum().backward()
    _expect(x.grad is not None and bool(x.grad.abs().sum() > 0), f"{cls.name}: no gradient reaches the node latents")
    trained = [p for p in processor.parameters() if p.requires_grad]
    _expect(bool(trained), f"{cls.name}: has no trainable parameters")
    no_grad = [name for name, p in processor.named_parameters() if p.requires_grad and p.grad is None]
    _expect(
        not no_grad,
        f"{cls.name}: parameters receive no gradient from the node latents (what the decoder reads): {no_grad}; "
        "give a component only parameters its node output depends on",
    )


def check_encoder(cls: type[Encoder], params: Mapping | None = None, sizes: ModelSizes | None = None) -> None:
    """Output shapes and finiteness of an encoder."""
    _expect(inspect.isclass(cls) and issubclass(cls, Encoder), f"{cls!r} is not an Encoder subclass")
    sizes = sizes or small_sizes()
    encoder = cls(cls.Params.model_validate(dict(params or {})), sizes)
    nodes, edges = encoder(torch.randn(7, sizes.node_in), torch.randn(11, sizes.edge_in))
    _expect(tuple(nodes.shape) == (7, sizes.latent), f"{cls.name}: node latent shape {tuple(nodes.shape)}")
    _expect(tuple(edges.shape) == (11, sizes.latent), f"{cls.name}: edge latent shape {tuple(edges.shape)}")
    _expect(bool(torch.isfinite(nodes).all() and torch.isfinite(edges).all()), f"{cls.name}: non-finite outputs")


def check_decoder(cls: type[Decoder], params: Mapping | None = None, sizes: ModelSizes | None = None) -> None:
    """Output shape, finiteness and row independence of a decoder (it acts per particle)."""
    _expect(inspect.isclass(cls) and issubclass(cls, Decoder), f"{cls!r} is not a Decoder subclass")
    sizes = sizes or small_sizes()
    decoder = cls(cls.Params.model_validate(dict(params or {})), sizes).double()
    latent = torch.randn(9, sizes.latent, dtype=torch.float64)
    out = decoder(latent)
    _expect(tuple(out.shape) == (9, sizes.output), f"{cls.name}: output shape {tuple(out.shape)}")
    _expect(bool(torch.isfinite(out).all()), f"{cls.name}: non-finite outputs")
    _expect(_close(decoder(latent[3:5]), out[3:5], 1e-12), f"{cls.name}: a row's output depends on other rows")


def check_integrator(cls: type[Integrator], params: Mapping | None = None, seed: int = 0) -> None:
    """``target`` inverts ``next_position``; both act per particle; ``predicts`` is valid."""
    _expect(inspect.isclass(cls) and issubclass(cls, Integrator), f"{cls!r} is not an Integrator subclass")
    _expect(cls.predicts in ("acceleration", "velocity"), f"{cls.name}: predicts = {cls.predicts!r}")
    integrator = cls(cls.Params.model_validate(dict(params or {})))
    generator = torch.Generator().manual_seed(seed)
    for dim in (2, 3):
        sequence = torch.randn(10, 6, dim, generator=generator, dtype=torch.float64)
        prediction = torch.randn(10, dim, generator=generator, dtype=torch.float64)
        next_position = integrator.next_position(sequence, prediction)
        _expect(
            tuple(next_position.shape) == (10, dim), f"{cls.name}: next_position shape {tuple(next_position.shape)}"
        )
        recovered = integrator.target(sequence, next_position)
        _expect(_close(recovered, prediction, 1e-10, 1e-10), f"{cls.name}: target(next_position(p)) != p")
        again = integrator.next_position(sequence, integrator.target(sequence, next_position))
        _expect(_close(again, next_position, 1e-10, 1e-10), f"{cls.name}: next_position(target(x)) != x")
        part = integrator.next_position(sequence[2:5], prediction[2:5])
        _expect(_close(part, next_position[2:5], 1e-12), f"{cls.name}: a particle's update depends on other particles")


def _canonical_edges(graph: Graph) -> set[tuple[int, int]]:
    return set(zip(graph.senders.tolist(), graph.receivers.tolist(), strict=True))


def _between_particles(graph: Graph, n: int, name: str) -> Graph:
    """``graph`` without the sink nodes of a fixed-size graph (``node_particle``), checking what joins them.

    Nodes from ``n`` on must stand for particles (``node_particle``), and an edge that touches one
    must join two of them (padding): no particle may receive a padding message.
    """
    if graph.node_particle is None:
        _expect(graph.num_nodes == n, f"{name}: num_nodes {graph.num_nodes}, expected {n}")
        return graph
    node_particle = graph.node_particle
    _expect(node_particle.shape == (graph.num_nodes,), f"{name}: node_particle must have one row per node")
    _expect(bool((node_particle[:n] == torch.arange(n)).all()), f"{name}: node i < N must be particle i")
    _expect(bool(((node_particle >= 0) & (node_particle < n)).all()), f"{name}: node_particle out of range")
    padding = graph.receivers >= n
    _expect(bool((graph.senders[padding] >= n).all()), f"{name}: a particle sends to a sink node")
    _expect(bool((graph.senders[~padding] < n).all()), f"{name}: a sink node sends to a particle")
    _expect(bool((padding[1:] >= padding[:-1]).all()), f"{name}: padding edges must come after every real edge")
    real = (~padding).nonzero()[:, 0]
    return replace(
        graph, senders=graph.senders[real], receivers=graph.receivers[real], displacement=graph.displacement[real]
    )


@renamed_keywords(scene="setup")
def check_graph_builder(
    cls: type[GraphBuilder], params: Mapping | None = None, setup: ModelSetup | None = None, seed: int = 0
) -> None:
    """Edge invariants of a graph builder on random scenes of two examples.

    Checks: int64 indices in range (sink nodes after the particles only joined to each other, for
    fixed-size graphs with ``node_particle``), displacements equal ``p_sender - p_receiver``
    (minimum image on periodic dimensions), no edge between examples, edges
    sorted by (receiver, sender) without duplicates, the same edges after a
    translation (by whole box lengths along periodic dimensions) and after
    renaming the particles.
    """
    _expect(inspect.isclass(cls) and issubclass(cls, GraphBuilder), f"{cls!r} is not a GraphBuilder subclass")
    setup = setup or small_scene()
    builder = cls(cls.Params.model_validate(dict(params or {})), setup)
    generator = torch.Generator().manual_seed(seed)
    lower = torch.tensor([b[0] for b in setup.bounds], dtype=torch.float64)
    upper = torch.tensor([b[1] for b in setup.bounds], dtype=torch.float64)
    counts = (30, 25)
    position = lower + (upper - lower) * torch.rand(sum(counts), setup.dim, generator=generator, dtype=torch.float64)
    batch = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts))
    n = position.shape[0]
    name = cls.name
    graph = _between_particles(builder.build(position, batch, len(counts)), n, name)

    _expect(graph.senders.dtype == torch.long and graph.receivers.dtype == torch.long, f"{name}: indices must be int64")
    _expect(graph.num_edges > 0, f"{name}: built no edges on a random scene")
    _expect(
        bool(((graph.senders >= 0) & (graph.senders < n) & (graph.receivers >= 0) & (graph.receivers < n)).all()),
        f"{name}: edge index out of range",
    )
    _expect(bool((batch[graph.senders] == batch[graph.receivers]).all()), f"{name}: an edge connects two examples")
    key = graph.receivers * n + graph.senders
    _expect(bool((key[1:] > key[:-1]).all()), f"{name}: edges not sorted by (receiver, sender) or duplicated")
    _expect(graph.receivers_sorted, f"{name}: sorted edges must say so: Graph(..., receivers_sorted=True)")
    box = PeriodicBox(setup)
    expected = box.minimum_image(position[graph.senders] - position[graph.receivers])
    _expect(_close(graph.displacement, expected, 1e-9), f"{name}: displacement != p_sender - p_receiver")

    shift = torch.rand(setup.dim, generator=generator, dtype=torch.float64) * 0.37
    if box.active:
        # Along periodic dimensions a translation is a relabelling of the box only by whole lengths.
        shift[box.dims] = torch.round(shift[box.dims]) * box.length + box.length
    moved = _between_particles(builder.build(position + shift, batch, len(counts)), n, name)
    _expect(_canonical_edges(moved) == _canonical_edges(graph), f"{name}: edges change under translation")

    perm = torch.cat([torch.randperm(c, generator=generator) + o for c, o in zip(counts, (0, counts[0]), strict=True)])
    renamed = _between_particles(builder.build(position[perm], batch, len(counts)), n, name)
    back = {(int(perm[s]), int(perm[r])) for s, r in _canonical_edges(renamed)}
    _expect(back == _canonical_edges(graph), f"{name}: edges are not permutation-equivariant")


def check_material(cls: type[Material], constitutive_models: Collection[str] | None = None) -> None:
    """Declared fields of a material: name, type id, flags, properties and what a simulator needs.

    Checks: a non-empty string name; an int ``particle_type`` in
    :data:`~gns_framework.contracts.PARTICLE_TYPE_IDS`; bool ``kinematic`` and
    ``granular`` (not both); well-formed ``properties``; a ``constitutive_model``
    that is None or one of ``constitutive_models`` (default: those the installed
    ground-truth simulators move); ``physical_parameters`` a mapping of names to
    finite numbers, with a positive ``density`` where given.
    """
    _expect(inspect.isclass(cls) and issubclass(cls, Material), f"{cls!r} is not a Material subclass")
    _expect(isinstance(getattr(cls, "name", None), str) and cls.name, f"{cls!r}: needs a non-empty string name")
    _expect(
        isinstance(getattr(cls, "particle_type", None), int)
        and not isinstance(cls.particle_type, bool)
        and cls.particle_type in PARTICLE_TYPE_IDS,
        f"{cls.name}: particle_type must be an int in {PARTICLE_TYPE_IDS.start}..{PARTICLE_TYPE_IDS.stop - 1}, "
        f"got {getattr(cls, 'particle_type', None)!r}",
    )
    _expect(isinstance(cls.kinematic, bool), f"{cls.name}: kinematic must be a bool")
    _expect(isinstance(cls.granular, bool), f"{cls.name}: granular must be a bool")
    _expect(
        not (cls.kinematic and cls.granular),
        f"{cls.name}: a kinematic material is not granular (it never moves freely)",
    )
    _expect(isinstance(cls.properties, tuple), f"{cls.name}: properties must be a tuple of MaterialProperty")
    names = [p.name for p in cls.properties]
    _expect(len(set(names)) == len(names), f"{cls.name}: duplicate property names {names}")
    for prop in cls.properties:
        _expect(isinstance(prop, MaterialProperty), f"{cls.name}: property {prop!r} is not a MaterialProperty")
        _expect(
            bool(prop.name) and bool(prop.description), f"{cls.name}: property {prop!r} needs a name and description"
        )
    if constitutive_models is None:
        from .plugins import load_registry

        registry = load_registry()
        constitutive_models = {m for e in registry.entries("simulator") for m in e.cls.constitutive_models}
    known = ", ".join(sorted(constitutive_models)) or "none installed"
    _expect(
        cls.constitutive_model is None or cls.constitutive_model in constitutive_models,
        f"{cls.name}: unknown constitutive_model {cls.constitutive_model!r}; the installed simulators move: {known} "
        "(None: no simulator generates it)",
    )
    _expect(isinstance(cls.physical_parameters, Mapping), f"{cls.name}: physical_parameters must be a dict")
    for key, value in cls.physical_parameters.items():
        _expect(
            isinstance(key, str)
            and isinstance(value, (int, float))
            and not isinstance(value, bool)
            and math.isfinite(value),
            f"{cls.name}: physical_parameters[{key!r}] must be a finite number, got {value!r}",
        )
    density = cls.physical_parameters.get("density")
    _expect(
        density is None or density > 0,
        f"{cls.name}: physical_parameters['density'] must be > 0 kg/m^3, got {density!r}",
    )


def _random_trajectories(count: int, dim: int, frames: int, types: tuple[int, ...], seed: int) -> list[Trajectory]:
    from .data.trajectory import Trajectory

    rng = np.random.default_rng(seed)
    return [
        Trajectory(
            (0.2 + 0.6 * rng.random((frames, 2 * len(types), dim))).astype(np.float32),
            np.repeat(np.asarray(types, dtype=np.int64), 2),
            key=f"trajectory_{i}",
        )
        for i in range(count)
    ]


def check_dataset(
    cls: type[Dataset], params: Mapping | None = None, path: str | Path | None = None, seed: int = 0
) -> None:
    """A dataset layout writes what it reads back, and reads a folder consistently.

    A writable layout writes a small random 2D and 3D dataset (train and valid splits)
    into a temporary folder, and reading it back must give the same metadata (bounds,
    dt, dim, frame count) and trajectories (positions, type ids, order); ``test``,
    not written, must be absent. On ``path`` (required for a read-only layout) every
    split it lists must hold trajectories of the metadata's dimension and frame count.
    """
    from .data.metadata import DatasetMetadata, compute_statistics

    _expect(inspect.isclass(cls) and issubclass(cls, Dataset), f"{cls!r} is not a Dataset subclass")
    _expect(isinstance(getattr(cls, "name", None), str) and cls.name, f"{cls!r}: needs a non-empty string name")
    _expect(cls.writable or path is not None, f"{cls.name}: a read-only layout is checked on a folder: pass path=")
    validated = cls.Params.model_validate(dict(params or {}))
    if cls.writable:
        for dim in (2, 3):
            splits = {
                split: _random_trajectories(count, dim, 7, (3, 5), seed + 10 * dim + i)
                for i, (split, count) in enumerate((("train", 2), ("valid", 1)))
            }
            metadata = DatasetMetadata(
                bounds=[(0.0, 1.0)] * dim,
                sequence_length=7,
                default_connectivity_radius=0.1,
                dim=dim,
                dt=0.01,
                **compute_statistics(splits["train"], kinematic_types=(3,)),
            )
            with tempfile.TemporaryDirectory() as folder:
                cls.write(Path(folder), metadata, splits)
                dataset = cls(validated, Path(folder))
                read = dataset.metadata()
                for key in ("dim", "sequence_length", "dt"):
                    _expect(
                        getattr(read, key) == getattr(metadata, key),
                        f"{cls.name}: metadata {key} changed on the round trip",
                    )
                _expect(
                    np.allclose(np.asarray(read.bounds, float), np.asarray(metadata.bounds, float)),
                    f"{cls.name}: metadata bounds changed on the round trip",
                )
                _expect(
                    dataset.splits() == ["train", "valid"],
                    f"{cls.name}: splits() is {dataset.splits()}, wrote train, valid",
                )
                _expect(not dataset.has_split("test"), f"{cls.name}: has_split('test') but no test split was written")
                for split, written in splits.items():
                    back = dataset.split(split)
                    _expect(
                        len(back) == len(written),
                        f"{cls.name}: {split}: {len(back)} trajectories, wrote {len(written)}",
                    )
                    for i, (a, b) in enumerate(zip(back, written, strict=True)):
                        _expect(
                            np.array_equal(np.asarray(a.position, np.float32), b.position),
                            f"{cls.name}: {split}[{i}]: positions changed on the round trip ({dim}D)",
                        )
                        _expect(
                            np.array_equal(np.asarray(a.particle_type), b.particle_type),
                            f"{cls.name}: {split}[{i}]: particle types changed on the round trip",
                        )
    if path is not None:
        dataset = cls(validated, Path(path))
        metadata = dataset.metadata()
        for split in dataset.splits():
            for i, trajectory in enumerate(dataset.split(split)):
                _expect(
                    trajectory.dim == metadata.dim,
                    f"{cls.name}: {split}[{i}] has dim {trajectory.dim}, metadata {metadata.dim}",
                )
                _expect(
                    trajectory.num_steps == metadata.sequence_length,
                    f"{cls.name}: {split}[{i}] has {trajectory.num_steps} frames, metadata sequence_length "
                    f"{metadata.sequence_length}",
                )


def check_simulator(
    cls: type[GroundTruthSimulator],
    scene: SceneSpec,
    materials: Mapping[str, type[Material]],
    params: Mapping | None = None,
    seed: int = 0,
) -> None:
    """A ground-truth simulator runs a small ``scene`` as its contract says.

    Checks: it has no problem with the scene (shared checks and its own
    :meth:`~gns_framework.contracts.GroundTruthSimulator.check`); it returns
    ``scene.time.frames`` frames of float32 positions (T, N, d), finite and inside
    the scene's bounds, with the type ids of the scene's materials; the same seed
    gives the same bits.
    """
    from .ground_truth.scene_checks import scene_problems

    _expect(
        inspect.isclass(cls) and issubclass(cls, GroundTruthSimulator),
        f"{cls!r} is not a GroundTruthSimulator subclass",
    )
    simulator = cls(cls.Params.model_validate(dict(params or {})), dict(materials))
    problems = scene_problems(simulator, scene)
    _expect(not problems, f"{cls.name}: cannot run the scene: {problems}")
    first, again = simulator.simulate(scene, seed), simulator.simulate(scene, seed)
    position = np.asarray(first.position)
    _expect(position.dtype == np.float32, f"{cls.name}: positions are {position.dtype}, not float32")
    _expect(
        position.ndim == 3 and position.shape[0] == scene.time.frames and position.shape[2] == scene.dim,
        f"{cls.name}: positions {position.shape}, expected ({scene.time.frames}, N, {scene.dim})",
    )
    _expect(bool(np.isfinite(position).all()), f"{cls.name}: non-finite positions")
    bounds = np.asarray(scene.domain.bounds, dtype=np.float64)
    _expect(
        bool(((position >= bounds[:, 0]) & (position <= bounds[:, 1])).all()),
        f"{cls.name}: positions leave the domain {bounds.tolist()}",
    )
    used = {materials[name].particle_type for _, name in scene.material_uses()}
    found = set(np.unique(first.particle_type).tolist())
    _expect(found <= used, f"{cls.name}: particle types {sorted(found - used)} belong to no material of the scene")
    _expect(
        np.array_equal(position, np.asarray(again.position))
        and np.array_equal(first.particle_type, again.particle_type),
        f"{cls.name}: the same seed gave different trajectories",
    )
