"""The halo: how deep it must be (the receptive field), and the particles in it, fetched from the processes that own them."""

from __future__ import annotations

import torch
from torch import Tensor

from ..errors import GnsError
from ..model.learned_simulator import LearnedSimulator
from .exchange import send_rows
from .particles import Particles
from .slabs import SlabPartition


def receptive_field(simulator: LearnedSimulator) -> float:
    """Connectivity radius x message-passing hops (dataset length units).

    Each message-passing step carries information one edge further, and no edge is
    longer than the connectivity radius, so a particle's output depends only on the
    particles within ``hops * R``: with that halo, the particles a process owns see
    exactly the inputs they would see in the whole scene. The encoder and decoder act
    on each particle and each edge alone (their contracts), so they add no reach.
    Refuses a graph builder or processor that does not declare such a bound.
    """
    builder, processor = simulator.graph_builder, simulator.processor
    problems = []
    if not type(builder).joins_within_radius:
        problems.append(
            f"graph builder {builder.name!r} joins particles by more than their own distance "
            "(joins_within_radius is False): use radius or periodic_radius"
        )
    hops_param = type(processor).hops_param
    if hops_param is None:
        problems.append(
            f"processor {processor.name!r} does not bound how far a particle's output reaches (hops_param is None)"
        )
    if problems:
        raise GnsError("a domain-decomposed rollout needs a bounded receptive field: " + "; ".join(problems))
    assert hops_param is not None
    return simulator.scene.connectivity_radius * int(getattr(processor.params, hops_param))


def with_halo(owned: Particles, partition: SlabPartition, world: int) -> tuple[Particles, Tensor, int]:
    """Owned plus halo particles, sorted by id; the owned particles' rows in it (in ``owned``'s order); the halo count.

    Every process calls it at once (the halo travels in one all-to-all). Sorted by id, the
    local particles keep the relative order they have in the whole scene, so a radius graph
    lists each owned particle's edges in the same order and its sums round the same way.
    """
    rows, destination = partition.halo_of(owned.sequence[:, -1]).nonzero(as_tuple=True)
    halo = Particles.of(send_rows(destination, owned.select(rows).columns(), world))
    local = owned.cat(halo)
    order = torch.argsort(local.ids)
    place = torch.empty_like(order)
    place[order] = torch.arange(order.shape[0], device=order.device)
    return local.select(order), place[: owned.ids.shape[0]], int(halo.ids.shape[0])
