"""The halo: which of two kinds, how deep, and the particles in it, fetched from the processes that own them.

Two ways to give the particles a process owns exactly the inputs they have in the whole scene:

- ``positions``: a halo as deep as the receptive field (connectivity radius x message-passing
  hops). Every process runs the whole model on owned plus halo particles; only the owned
  outputs are right, and they are all that is kept. One exchange per step, extra compute
  in proportion to the halo. Works with every processor that bounds its hops.
- ``latents``: a halo one connectivity radius deep, and after each message-passing step the
  owners send the halo particles' new node latents. Edges are kept only where an owned
  particle receives. Hops exchanges per step, almost no extra compute. Needs a processor that
  calls the exchange between its steps (``Processor.exchanges_latents``).

Which costs less depends on the halo's share of the scene against the cost of an exchange:
docs/domain_decomposition.md measures both terms and projects them to many GPUs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor

from ..contracts import GraphBuilder, Processor
from ..errors import GnsError
from ..model.learned_simulator import LearnedSimulator
from .exchange import Routing
from .particles import Particles
from .partition import Cut, Partition, balanced_partition
from .space import CutOptions
from .work import particle_work

HaloKind = Literal["auto", "positions", "latents"]


def receptive_field(simulator: LearnedSimulator) -> float:
    """Connectivity radius x message-passing hops (dataset length units).

    Each message-passing step carries information one edge further, and no edge is
    longer than the connectivity radius, so a particle's output depends only on the
    particles within ``hops * R``: with that halo, the particles a process owns see
    exactly the inputs they would see in the whole scene. The encoder and decoder act
    on each particle and each edge alone (their contracts), so they add no reach.
    Refuses a graph builder or processor that does not declare such a bound.
    """
    processor = simulator.processor
    problems = unbounded_reach(type(simulator.graph_builder), type(processor))
    if problems:
        raise GnsError("a domain-decomposed rollout needs a bounded receptive field: " + "; ".join(problems))
    hops_param = type(processor).hops_param
    assert hops_param is not None
    return simulator.setup.connectivity_radius * int(getattr(processor.params, hops_param))


def unbounded_reach(builder: type[GraphBuilder], processor: type[Processor]) -> list[str]:
    """Why a model of these components cannot be split over processes (empty when it can): the facts they declare."""
    problems = []
    if not builder.joins_within_radius:
        problems.append(
            f"graph builder {builder.name!r} joins particles by more than their own distance "
            "(joins_within_radius is False): use radius or periodic_radius"
        )
    if processor.hops_param is None:
        problems.append(
            f"processor {processor.name!r} does not bound how far a particle's output reaches (hops_param is None)"
        )
    return problems


def halo_kind(simulator: LearnedSimulator, requested: HaloKind) -> Literal["positions", "latents"]:
    """``requested``, or for ``auto`` latents where the processor exchanges them, else positions."""
    exchanges = type(simulator.processor).exchanges_latents
    if requested == "auto":
        return "latents" if exchanges else "positions"
    if requested == "latents" and not exchanges:
        raise GnsError(
            f"processor {simulator.processor.name!r} does not exchange node latents between its message-passing "
            "steps (exchanges_latents is False): use the halo of positions (halo: positions)"
        )
    return requested


def halo_depth(simulator: LearnedSimulator, kind: Literal["positions", "latents"]) -> float:
    """The receptive field for a halo of positions; one connectivity radius for a halo of latents."""
    reach = receptive_field(simulator)  # refuses what has no bounded reach, for either kind
    return reach if kind == "positions" else simulator.setup.connectivity_radius


def partition_for(
    simulator: LearnedSimulator,
    position: Tensor,
    parts: int,
    halo: HaloKind = "auto",
    axis: int | None = None,
    cut: Cut = "auto",
    weight: Tensor | None = None,
    by_work: bool = True,
    halo_weight: Tensor | None = None,
) -> tuple[Partition, Literal["positions", "latents"]]:
    """Pieces of equal work of the scene at ``position`` (N, d) (each particle one plus the edges it receives in
    the model's graph, :func:`.work.particle_work`, unless ``weight`` gives it), cut as ``cut`` says
    (:func:`.partition.balanced_partition`), with the halo ``halo`` resolves to. Each cut also weighs the halo it
    makes (:func:`.work.halo_cut`): ``halo_weight`` (N,), by default each particle's work for a halo of positions
    (the piece computes its edges too) and one for a halo of latents (a node). ``by_work`` False: pieces of
    equal particle count, halos not weighed (a training step cuts its windows afresh every step: weighing them
    would add a graph).
    """
    kind = halo_kind(simulator, halo)
    setup = simulator.setup
    depth = halo_depth(simulator, kind)
    if weight is None and by_work:  # from the whole scene's graph (a re-cut passes what each process weighed)
        with torch.no_grad():
            weight = particle_work(simulator.graph_builder, position)
    if by_work and halo_weight is None:
        halo_weight = weight if kind == "positions" else torch.ones(len(position), device=position.device)
    options = CutOptions(periodic_dims=setup.periodic_dims, bounds=setup.bounds, weight=weight, halo_weight=halo_weight)
    return balanced_partition(position, parts, depth, cut, axis, **options), kind


@dataclass(frozen=True)
class Halo:
    """A process's particles for one step: its own and its halo, sorted by global id.

    Sorted by id, the local particles keep the relative order they have in the whole scene,
    so a radius graph lists each owned particle's edges in the same order, and its sums
    round the same way.

    Attributes:
        local: owned plus halo particles, sorted by id.
        owned_rows: (n,) the owned particles' rows in ``local``, in the owned particles' order.
        halo_rows: (h,) the halo particles' rows in ``local``, in the order they arrived.
        sent_rows: the rows in ``local`` of the owned particles sent as others' halo, one per sending.
        routing: where those go.
    """

    local: Particles
    owned_rows: Tensor
    halo_rows: Tensor
    sent_rows: Tensor
    routing: Routing

    @property
    def halo_count(self) -> int:
        return int(self.halo_rows.shape[0])

    def refresh(self, node_latent: Tensor) -> Tensor:
        """(n + h, L) node latents with the halo rows replaced by their owners' (differentiable)."""
        incoming = self.routing.send(node_latent.index_select(0, self.sent_rows))
        return node_latent.index_copy(0, self.halo_rows, incoming.to(node_latent.dtype))


def with_halo(owned: Particles, partition: Partition, world: int, group: Any = None) -> Halo:
    """This process's particles plus the halo ``partition`` gives it; every process of ``group`` (None: the whole
    job, of ``world`` processes) calls it at once."""
    rows, destination = partition.halo_of(owned.sequence[:, -1]).nonzero(as_tuple=True)
    routing = Routing.of(destination, world, group)
    halo = Particles.of([None if c is None else routing.send(c[rows]) for c in owned.columns()])
    local = owned.cat(halo)
    order = torch.argsort(local.ids)
    place = torch.empty_like(order)
    place[order] = torch.arange(order.shape[0], device=order.device)
    owned_rows = place[: owned.count]
    return Halo(local.select(order), owned_rows, place[owned.count :], owned_rows[rows], routing)
