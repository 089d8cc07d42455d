"""One piece of a scene split over processes: the batch a process runs the model on, and the step it skips.

Every use of the decomposition (rollout, push-forward, training step, validation)
predicts on its piece the same way: the owned particles and their halo as one batch
with what the whole scene shares (context, walls), and with a halo of latents the
owned-receivers filter and the latent exchange carried by the batch into the graph
build (:meth:`~gns_framework.model.learned_simulator.LearnedSimulator.build_graph`).
A process with nothing to predict still takes part in the others' exchanges.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Literal, TypeVar

import torch

from ..data.batch import ParticleBatch
from ..model.learned_simulator import LearnedSimulator
from .halo import Halo

T = TypeVar("T")


def piece_batch(scene: ParticleBatch, piece: Halo, kind: Literal["positions", "latents"]) -> ParticleBatch:
    """``scene``'s shared fields with the piece's particles (owned plus halo, sorted by id).

    Shapes: the piece's n + h particles: position_sequence (n + h, C, d), particle_type
    (n + h,), ``owned`` (n + h,) bool with a halo of latents. ``scene``'s own particle
    fields are replaced; ``ahead`` (push-forward targets) is not split and is dropped.
    """
    local = piece.local
    latents = kind == "latents"
    # Only a halo of latents filters the graph by receiver; a halo of positions keeps every edge.
    owned = (
        torch.zeros(local.count, dtype=torch.bool, device=local.ids.device).index_fill(0, piece.owned_rows, True)
        if latents
        else None
    )
    return replace(
        scene,
        position_sequence=local.sequence,
        particle_type=local.particle_type,
        material_property=local.material_property,
        next_position=local.next_position,
        batch=local.example if local.example is not None else torch.zeros_like(local.ids),
        ahead=None,
        owned=owned,
        exchange=piece.refresh if latents else None,
    )


def on_piece(
    simulator: LearnedSimulator,
    piece: Halo,
    kind: Literal["positions", "latents"],
    scene: ParticleBatch,
    run: Callable[[ParticleBatch], T],
    backward: bool = False,
) -> T | None:
    """``run(batch)`` on this process's piece (:func:`piece_batch`); None where it has nothing to predict.

    Every process of the step calls it at once. With a halo of positions a process that
    owns nothing skips the step; with a halo of latents one that holds no particle at all
    stands in for each exchange of the forward (and, ``backward``, of the backward) pass,
    or the others would wait for it forever.
    """
    if piece.local.count == 0 or (kind == "positions" and piece.owned_rows.numel() == 0):
        if kind == "latents":
            stand_in_exchanges(simulator, piece, backward)
        return None
    return run(piece_batch(scene, piece, kind))


def stand_in_exchanges(simulator: LearnedSimulator, piece: Halo, backward: bool) -> None:
    """The exchanges of a step with a halo of latents, for a process with no particle (none owned, no halo).

    It sends and receives nothing, but each exchange is collective.
    """
    hops_param = type(simulator.processor).hops_param
    assert hops_param is not None and piece.local.count == 0
    latent = torch.zeros((0, 1), device=piece.owned_rows.device, requires_grad=backward)
    for _ in range(int(getattr(simulator.processor.params, hops_param)) - 1):
        latent = piece.refresh(latent)
    if backward:
        latent.sum().backward()
