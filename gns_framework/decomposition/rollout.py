"""A rollout of one scene over several processes: each owns a piece of it and predicts only its own particles.

Every step, on every process (rank r of P):

1. **halo**: send each other process the particles it needs (:mod:`.halo`): those within the
   receptive field (connectivity radius x message-passing hops) of its piece (a slab,
   :class:`.slabs.SlabPartition`, or a block, :class:`.blocks.BlockPartition`) for a halo
   of positions, within one radius for a halo of latents;
2. **predict** the next positions of owned plus halo particles, sorted by global particle id:
   the radius graph lists edges by (receiver, sender), so every owned particle sums its
   messages in the same order as in the whole scene, and its prediction is the same (with a
   halo of latents the halo's node latents come from their owners between message-passing steps);
3. **gather** the owned particles' next positions on rank 0, which checks the frame with the
   rollout guard as a single process does, and keeps it;
4. **migrate**: particles whose new position lies in another piece move to that process;
5. **rebalance**: when a process now holds more than ``rebalance`` times its share of the
   particles (they crowd as a column collapses or a flow runs out), every process receives
   the whole frame, the pieces are cut afresh from it, and the particles migrate to them.
   Ownership changes nothing in the predictions, only who computes them.

With a halo of positions, its outermost particles miss some of their own neighbours, but what
they get wrong travels one edge per message-passing step and never reaches an owned particle. Memory per
process is its share of the scene plus the halo; rank 0 alone also holds the predicted
frames (as the rollout file does), in memory or in a memory-mapped file (``frames``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from ..data.batch import window
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import GnsError, RolloutDiverged
from ..model.history import advance_window
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout import check_simulates, rollout_step
from ..model.rollout_guard import GuardViolation, RolloutGuard
from ..runtime.precision import Precision
from .exchange import rows_everywhere, send_rows
from .halo import HaloKind, partition_for, with_halo
from .particles import Particles
from .partition import Cut, Partition
from .piece import on_piece
from .work import particle_work

if TYPE_CHECKING:
    from ..runtime.processes import Processes


@dataclass(frozen=True)
class DecompositionStats:
    """What the decomposition cost, summed over steps and processes.

    Attributes:
        owned: particle-steps predicted (N x steps).
        halo: halo particle-steps held beside them; ``halo / owned`` is the halo fraction.
        migrations: particles that moved to another process.
        rebalances: times the pieces were cut afresh.
        partition: the pieces (slabs or blocks).
        halo_kind: ``positions`` or ``latents`` (:mod:`.halo`).
    """

    owned: int
    halo: int
    migrations: int
    partition: Partition
    halo_kind: str
    rebalances: int = 0

    @property
    def halo_fraction(self) -> float:
        return self.halo / max(self.owned, 1)


@torch.inference_mode()
def partitioned_rollout(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    processes: Processes,
    steps: int | None = None,
    device: torch.device | str = "cpu",
    guard: RolloutGuard | None = None,
    precision: Precision = "float32",
    axis: int | None = None,
    halo: HaloKind = "auto",
    cut: Cut = "auto",
    rebalance: float | None = 1.25,
    frames: Path | None = None,
) -> tuple[Rollout | None, DecompositionStats]:
    """Predict ``steps`` frames from the first C of ``trajectory``, the scene split over ``processes``.

    Every process of the (started) process group calls it with the same arguments. Returns,
    on rank 0, the rollout as :func:`gns_framework.model.rollout.rollout` gives it (None on the
    others), and on every process the decomposition's statistics. A guard stop raises
    :class:`~gns_framework.errors.RolloutDiverged` on every process (rank 0 the guard's, the
    others one naming the step).

    Args:
        axis: the dimension cut into slabs (default: the one the particles spread farthest in); slabs only.
        cut: ``slabs``, ``blocks`` (recursive bisection) or ``auto``: whichever leaves the smaller halo
            at the first frame (:mod:`.partition`).
        halo: ``positions`` (as deep as the receptive field), ``latents`` (one radius deep, latents
            exchanged between message-passing steps), or ``auto``: latents where the processor
            exchanges them (:mod:`.halo`).
        rebalance: cut the pieces afresh when a process holds more than this many times its share
            of the particles (> 1; None: keep the first frame's pieces).
        frames: where rank 0 keeps the predicted frames, a ``.npy`` file it memory-maps, so
            that a long rollout of a large scene need not fit in its memory (steps x N x d
            float32); None: in memory. The rollout's ``predicted`` is then backed by that file.
    """
    if rebalance is not None and not rebalance > 1:
        raise ValueError(f"rebalance must be more than 1 (a process's most particles over its share), got {rebalance}")
    check_simulates(simulator, trajectory)
    setup = simulator.setup
    guard = guard if guard is not None else RolloutGuard(setup)
    if trajectory.bounds is not None:
        guard = guard.with_bounds(trajectory.bounds)
    device = torch.device(device)
    history = setup.history
    available = trajectory.num_steps - history
    steps = available if steps is None else min(steps, available)
    if steps < 1:
        raise ValueError(
            f"trajectory {trajectory.key!r} has {trajectory.num_steps} frames; rollout needs more than {history}"
        )
    rank, world = processes.rank, processes.world_size
    start = window(trajectory, 0, history, with_target=False)
    partition, kind = partition_for(simulator, start.position_sequence[:, -1], world, halo, axis, cut)
    everyone = Particles(
        torch.arange(start.num_particles), start.position_sequence, start.particle_type, start.material_property
    )
    mine = partition.owner(start.position_sequence[:, -1]) == rank
    owned = everyone.select(mine).to(device)
    # What the whole scene shares (its walls) is the same on every process; the particle fields are set per step.
    nothing = start.particle_type[:0]
    shared = replace(start, position_sequence=start.position_sequence[:0], particle_type=nothing, batch=nothing)
    shared = replace(shared, material_property=None).to(device)
    context = None if trajectory.step_context is None else torch.from_numpy(trajectory.step_context).to(device)
    chief = rank == 0
    predicted = _frames(frames, (steps, start.num_particles, setup.dim)) if chief else None
    last_input = torch.from_numpy(np.array(trajectory.position[history - 1])) if chief else None
    violations: list[GuardViolation] = []
    halo_count = migrations = rebalances = 0
    for step in range(steps):
        particles = with_halo(owned, partition, world, processes.group)
        local, owned_rows = particles.local, particles.owned_rows
        halo_count += particles.halo_count
        kinematic = owned_rows[~simulator.predicted_mask(owned.particle_type)]
        kinematic_ids = local.ids[kinematic].cpu().numpy()
        kinematic_next = torch.from_numpy(np.asarray(trajectory.position[history + step][kinematic_ids])).to(device)
        scene_now = replace(shared, context=None if context is None else context[history - 1 + step][None])
        step_on_piece = partial(
            rollout_step, simulator, guard, kinematic=kinematic, kinematic_next=kinematic_next, precision=precision
        )
        result = on_piece(simulator, particles, kind, scene_now, step_on_piece)
        if result is None:
            next_position = continued = local.sequence[:0, -1]
        else:
            next_position, continued = result
        next_owned, continued_owned = next_position[owned_rows], continued[owned_rows]
        previous = None if predicted is None else (predicted[step - 1] if step > 0 else last_input)
        violations += _gather_and_check(
            owned.ids, next_owned, predicted, previous, step, guard, trajectory.key, processes
        )
        owned = replace(owned, sequence=advance_window(owned.sequence, continued_owned))
        owned, moved = _migrate(owned, partition, processes)
        migrations += moved
        if (
            rebalance is not None
            and world > 1
            and _most_held(owned, processes) > rebalance * start.num_particles / world
        ):
            # Each process weighs its own particles on its piece's graph: no process builds the whole scene's.
            # The work (whole edge counts, exact in float32) travels beside the positions, in one exchange.
            work = _owned_work(simulator, owned, partition, processes)
            last = owned.sequence[:, -1]
            rows = torch.cat([last, work[:, None].to(last.dtype)], dim=1)
            everywhere = rows_everywhere(owned.ids, rows, start.num_particles, world, processes.group)
            frame, work = everywhere[:, :-1], everywhere[:, -1].to(torch.float64)
            partition, _ = partition_for(simulator, frame, world, kind, axis, cut, weight=work)
            owned, moved = _migrate(owned, partition, processes)
            migrations += moved
            rebalances += 1
    totals = processes.sum(torch.tensor([halo_count, migrations], dtype=torch.long, device=device))
    stats = DecompositionStats(start.num_particles * steps, int(totals[0]), int(totals[1]), partition, kind, rebalances)
    if not chief:
        return None, stats
    assert predicted is not None
    return (
        Rollout(
            truth=trajectory.first_frames(history + steps),
            predicted=predicted.numpy(),
            history=history,
            predicted_particles=simulator.predicted_mask(start.particle_type.to(device)).cpu().numpy(),
            guard_violations=tuple(violations),
        ),
        stats,
    )


def _gather_and_check(
    ids: Tensor,
    next_owned: Tensor,
    predicted: Tensor | None,
    previous: Tensor | None,
    step: int,
    guard: RolloutGuard,
    key: str,
    processes: Processes,
) -> list[GuardViolation]:
    """Frame ``step`` assembled in ``predicted`` on rank 0 and checked by the guard against ``previous``.

    Returns what the guard clamped. A guard stop raises RolloutDiverged on every process: rank 0
    the guard's, the others one that points to it.
    """
    gathered_ids, gathered = send_rows(torch.zeros_like(ids), [ids, next_owned], processes.world_size, processes.group)
    found: list[GuardViolation] = []
    failure: GnsError | None = None
    if predicted is not None:
        assert gathered_ids is not None and gathered is not None and previous is not None
        frame = torch.empty_like(predicted[step])
        frame[gathered_ids.cpu()] = gathered.cpu()
        try:
            predicted[step], found = guard.check(step, frame, previous, key)
        except GnsError as exc:
            failure = exc
    # Only rank 0 checks, so the sum over the processes is its verdict, on every process.
    stopped = processes.sum(torch.tensor([failure is not None], dtype=torch.long, device=next_owned.device))
    if failure is not None:
        raise failure
    if bool(stopped):
        raise RolloutDiverged(
            f"rank 0 stopped the rollout of trajectory {key!r} at step {step} (its error says why)", key, step
        )
    return found


def _frames(path: Path | None, shape: tuple[int, int, int]) -> Tensor:
    """(steps, N, d) float32 frames: in memory, or in a memory-mapped ``.npy`` file at ``path``."""
    if path is None:
        return torch.empty(shape)
    return torch.from_numpy(np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=shape))


def _owned_work(simulator: LearnedSimulator, owned: Particles, partition: Partition, processes: Processes) -> Tensor:
    """(n,) float64 work of this process's particles (:func:`.work.particle_work`), on its piece with its halo:
    the halo holds every neighbour within the connectivity radius, so each owned particle's edges are all there."""
    local = with_halo(owned, partition, processes.world_size, processes.group)
    with torch.no_grad():
        work = particle_work(simulator.graph_builder, local.local.sequence[:, -1])
    return work[local.owned_rows]


def _most_held(owned: Particles, processes: Processes) -> int:
    """The most particles any process holds (the same answer on every process)."""
    held = torch.zeros(processes.world_size, dtype=torch.long, device=owned.ids.device)
    held[processes.rank] = owned.count
    return int(processes.sum(held).max())


def _migrate(owned: Particles, partition: Partition, processes: Processes) -> tuple[Particles, int]:
    """Particles now in another piece sent to its process, those arriving appended; and how many left."""
    owner = partition.owner(owned.sequence[:, -1])
    leaving = owner != processes.rank
    moving = owned.select(leaving).columns()
    arrived = Particles.of(send_rows(owner[leaving], moving, processes.world_size, processes.group))
    return owned.select(~leaving).cat(arrived), int(leaving.sum())
