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
3. **check and hand over**: each process runs the rollout guard on its own particles' next
   positions (only the verdict travels, one sum) and hands their rows to the output: gathered
   into whole frames on rank 0 (:func:`partitioned_rollout`, for scenes that fit one process),
   or written by every process into its own shard of a sharded rollout (:func:`sharded_rollout`);
4. **migrate**: particles whose new position lies in another piece move to that process;
5. **rebalance**: when a process now holds more than ``rebalance`` times its share of the
   particles (they crowd as a column collapses or a flow runs out), the pieces are cut afresh
   from the scene's work on a coarse grid (:func:`.work.work_summary`: no process holds the
   whole frame), each cut weighing the halo it makes too (:func:`.work.halo_cut`), and the
   particles whose owner changed migrate.
   Ownership changes nothing in the predictions, only who computes them.

With a halo of positions, its outermost particles miss some of their own neighbours, but what
they get wrong travels one edge per message-passing step and never reaches an owned particle. Memory per
process is its share of the scene plus the halo; with gathered frames rank 0 also holds the predicted
frames (as the rollout file does), with a sharded output no process does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, TypedDict, Unpack

import numpy as np
import torch
from torch import Tensor

from ..data.batch import window
from ..data.in_parts import particle_run
from ..data.metadata import DatasetMetadata
from ..data.rollout import Rollout
from ..data.trajectory import Trajectory
from ..errors import DatasetError, GnsError, RolloutDiverged
from ..io.sharded_rollout import RolloutShard, write_manifest
from ..model.history import advance_window
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout import check_simulates, rollout_step
from ..model.rollout_guard import GuardViolation, RolloutGuard, merged_violations
from ..runtime.precision import Precision
from .exchange import objects_everywhere, send_rows
from .halo import HaloKind, partition_for, with_halo
from .particles import Particles
from .partition import Cut, Partition
from .piece import on_piece
from .work import particle_work, work_summary

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
) -> tuple[Rollout | None, DecompositionStats]:
    """Predict ``steps`` frames from the first C of ``trajectory``, the scene split over ``processes``, every
    frame gathered on rank 0: for scenes that fit one process (validation, tests); :func:`sharded_rollout`
    writes a large one in pieces instead.

    Every process of the (started) process group calls it with the same arguments. Returns,
    on rank 0, the rollout as :func:`gns_framework.model.rollout.rollout` gives it (None on the
    others), and on every process the decomposition's statistics. A guard stop raises
    :class:`~gns_framework.errors.RolloutDiverged` on every process (the guard's on the process
    whose particles it stopped, one naming the step on the others).

    Args:
        axis: the dimension cut into slabs (default: the one the particles spread farthest in); slabs only.
        cut: ``slabs``, ``blocks`` (recursive bisection) or ``auto``: whichever leaves the smaller halo
            at the first frame (:mod:`.partition`).
        halo: ``positions`` (as deep as the receptive field), ``latents`` (one radius deep, latents
            exchanged between message-passing steps), or ``auto``: latents where the processor
            exchanges them (:mod:`.halo`).
        rebalance: cut the pieces afresh when a process holds more than this many times its share
            of the particles (> 1; None: keep the first frame's pieces).
    """
    output = _Gathered(processes)
    options = RolloutOptions(
        steps=steps, device=device, guard=guard, precision=precision, axis=axis, halo=halo, cut=cut, rebalance=rebalance
    )
    stats, violations = _roll(simulator, trajectory, processes, output, options)
    everyone = _everyones(violations, processes)
    if output.predicted is None:
        return None, stats
    return (
        Rollout(
            truth=trajectory.first_frames(simulator.setup.history + len(output.predicted)),
            predicted=output.predicted.numpy(),
            history=simulator.setup.history,
            predicted_particles=simulator.predicted_mask(torch.as_tensor(trajectory.particle_type)).numpy(),
            guard_violations=tuple(everyone),
        ),
        stats,
    )


class RolloutOptions(TypedDict, total=False):
    """The options of :func:`partitioned_rollout` after its first three arguments, by keyword."""

    steps: int | None
    device: torch.device | str
    guard: RolloutGuard | None
    precision: Precision
    axis: int | None
    halo: HaloKind
    cut: Cut
    rebalance: float | None


@dataclass(frozen=True)
class WrittenRollout:
    """What :func:`sharded_rollout` wrote: the folder, the frames predicted, the position MSE over them (over
    steps, predicted particles and dimensions, as :attr:`Rollout.position_mse`), and what the guard clamped."""

    folder: Path
    num_steps: int
    position_mse: float
    guard_violations: tuple[GuardViolation, ...]


def sharded_rollout(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    processes: Processes,
    folder: Path,
    metadata: DatasetMetadata,
    **options: Unpack[RolloutOptions],
) -> tuple[WrittenRollout, DecompositionStats]:
    """:func:`partitioned_rollout` written in pieces: each process writes its own particles' frames into its
    shard of a sharded rollout in ``folder`` as the rollout goes (:mod:`gns_framework.io.sharded_rollout`),
    rank 0 the manifest with ``metadata`` once all are complete; no process ever gathers a frame. A rollout
    that stops leaves no shard behind. Returns the same record on every process; ``options`` are
    :func:`partitioned_rollout`'s."""
    shard = RolloutShard(folder, processes.rank)
    output = _Sharded(shard, trajectory, simulator.setup.history, simulator)
    try:
        stats, violations = _roll(simulator, trajectory, processes, output, options)
    except BaseException:
        shard.abandon()
        raise
    shard.finish(violations)
    squared, count = processes.sum(torch.tensor([output.squared_error, output.predicted_values])).tolist()
    processes.barrier()  # every shard complete before the manifest says so
    if processes.is_chief:
        write_manifest(folder, trajectory, output.steps, simulator.setup.history, processes.world_size, metadata)
    written = WrittenRollout(folder, output.steps, squared / max(count, 1.0), tuple(_everyones(violations, processes)))
    return written, stats


def _everyones(violations: list[GuardViolation], processes: Processes) -> list[GuardViolation]:
    """What the guard found on every process's particles, merged as one check of whole frames reports it."""
    return merged_violations(v for found in objects_everywhere(processes, violations) for v in found)


@torch.inference_mode()
def _roll(
    simulator: LearnedSimulator,
    trajectory: Trajectory,
    processes: Processes,
    output: _Output,
    options: RolloutOptions,
) -> tuple[DecompositionStats, list[GuardViolation]]:
    """The rollout's steps on this process: its particles' checked frames go to ``output`` step by step.

    Returns the statistics and what the guard found on this process's particles (numbered in the scene).
    """
    steps, guard, precision = options.get("steps"), options.get("guard"), options.get("precision", "float32")
    axis, halo, cut = options.get("axis"), options.get("halo", "auto"), options.get("cut", "auto")
    rebalance = options.get("rebalance", 1.25)
    if rebalance is not None and not rebalance > 1:
        raise ValueError(f"rebalance must be more than 1 (a process's most particles over its share), got {rebalance}")
    check_simulates(simulator, trajectory)
    setup = simulator.setup
    guard = guard if guard is not None else RolloutGuard(setup)
    if trajectory.bounds is not None:
        guard = guard.with_bounds(trajectory.bounds)
    device = torch.device(options.get("device", "cpu"))
    history = setup.history
    available = trajectory.num_steps - history
    steps = available if steps is None else min(steps, available)
    if steps < 1:
        raise ValueError(
            f"trajectory {trajectory.key!r} has {trajectory.num_steps} frames; rollout needs more than {history}"
        )
    world, total = processes.world_size, trajectory.num_particles
    # Each process reads and checks an equal run of the particles, the pieces are cut by count from a coarse
    # summary of their input frames, the particles go to their owners, and the pieces are cut again by the work
    # each process weighs on its own piece: no process reads or holds the whole scene's frames.
    run = particle_run(total, processes.rank, world)
    start = window(_checked_run(trajectory, run, processes, device), 0, history, with_target=False)
    ids = torch.arange(run.start, run.stop)
    owned = Particles(ids, start.position_sequence, start.particle_type, start.material_property).to(device)
    centres, _, counts = work_summary(owned.sequence[:, -1], torch.ones(owned.count), total, processes)
    partition, kind = partition_for(simulator, centres, world, halo, axis, cut, weight=counts, halo_weight=counts)
    owned, _ = _migrate(owned, partition, processes)
    partition, owned, _ = _recut(simulator, owned, partition, processes, kind, axis, cut, total)
    output.begin(owned, steps, total)
    # What the whole scene shares (its walls) is the same on every process; the particle fields are set per step.
    nothing = start.particle_type[:0]
    shared = replace(start, position_sequence=start.position_sequence[:0], particle_type=nothing, batch=nothing)
    shared = replace(shared, material_property=None).to(device)
    context = None if trajectory.step_context is None else torch.from_numpy(trajectory.step_context).to(device)
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
        checked, found = _checked(guard, step, next_owned, owned, trajectory.key, processes)
        violations += found
        output.frame(step, owned, checked)
        owned = replace(owned, sequence=advance_window(owned.sequence, continued_owned))
        owned, moved = _migrate(owned, partition, processes)
        migrations += moved
        if rebalance is not None and world > 1 and _most_held(owned, processes) > rebalance * total / world:
            partition, owned, moved = _recut(simulator, owned, partition, processes, kind, axis, cut, total)
            migrations += moved
            rebalances += 1
    totals = processes.sum(torch.tensor([halo_count, migrations], dtype=torch.long, device=device))
    stats = DecompositionStats(total * steps, int(totals[0]), int(totals[1]), partition, kind, rebalances)
    return stats, violations


def _checked(
    guard: RolloutGuard, step: int, next_owned: Tensor, owned: Particles, key: str, processes: Processes
) -> tuple[Tensor, list[GuardViolation]]:
    """This process's particles' next positions as the guard lets them stand, and what it found on them.

    Each process checks its own particles; only the verdict travels (one sum). A guard stop raises
    RolloutDiverged on every process: the guard's own where it stopped, one naming the step elsewhere.
    """
    failure: GnsError | None = None
    try:
        checked, found = guard.check(step, next_owned, owned.sequence[:, -1], key, ids=owned.ids)
    except GnsError as exc:
        failure, checked, found = exc, next_owned, []
    message = f"another process stopped the rollout of trajectory {key!r} at step {step} (its error says why)"
    _stop_together(failure, processes, next_owned.device, lambda: RolloutDiverged(message, key, step))
    return checked, found


def _checked_run(trajectory: Trajectory, run: slice, processes: Processes, device: torch.device) -> Trajectory:
    """This process's ``run`` of the particles, its positions checked where the scene left them to the runs
    (:mod:`gns_framework.data.in_parts`); data refused on any process stops every process."""
    failure: GnsError | None = None
    try:
        part = trajectory.particles(run)
    except GnsError as exc:
        failure, part = exc, trajectory
    message = f"trajectory {trajectory.key!r}: another process refused its particles (its error says why)"
    _stop_together(failure, processes, device, lambda: DatasetError(message))
    return part


def _stop_together(
    failure: GnsError | None, processes: Processes, device: torch.device, stopped: Callable[[], GnsError]
) -> None:
    """Where any process failed, every process stops (one sum): those that failed with their own error, the others
    with ``stopped()``; on the processes' device, as NCCL reduces CUDA tensors only."""
    failed = processes.sum(torch.tensor([failure is not None], dtype=torch.long, device=device))
    if failure is not None:
        raise failure
    if bool(failed):
        raise stopped()


class _Output(Protocol):
    """Where a partitioned rollout's frames go, each process handing over its own particles' rows."""

    def begin(self, owned: Particles, steps: int, particles: int) -> None:
        """The particles this process owns at the start (their C input frames), before the first step."""

    def frame(self, step: int, owned: Particles, position: Tensor) -> None:
        """Step ``step``'s checked positions (n, d) of the particles this process owns at that step."""


class _Gathered:
    """Every frame on rank 0, each process sending it its particles' rows (whole frames on one process)."""

    def __init__(self, processes: Processes):
        self.processes = processes
        self.predicted: Tensor | None = None

    def begin(self, owned: Particles, steps: int, particles: int) -> None:
        if self.processes.is_chief:
            self.predicted = torch.empty((steps, particles, owned.sequence.shape[-1]))

    def frame(self, step: int, owned: Particles, position: Tensor) -> None:
        rows = _on_chief(self.processes, owned.ids, position)
        if rows is not None and self.predicted is not None:
            self.predicted[step] = rows.cpu()


class _Sharded:
    """Each process's rows into its own shard (:class:`~gns_framework.io.sharded_rollout.RolloutShard`), beside
    their true positions; the squared error of the predicted particles summed on the way."""

    def __init__(self, shard: RolloutShard, trajectory: Trajectory, history: int, simulator: LearnedSimulator):
        self.shard, self.trajectory, self.history, self.simulator = shard, trajectory, history, simulator
        self.squared_error = self.predicted_values = 0.0
        self.steps = 0

    def begin(self, owned: Particles, steps: int, particles: int) -> None:
        self.steps = steps
        prop = owned.material_property
        self.shard.start(
            owned.ids.cpu().numpy(),
            owned.sequence.transpose(0, 1).cpu().numpy(),
            owned.particle_type.cpu().numpy(),
            None if prop is None else prop.cpu().numpy(),
            self.simulator.predicted_mask(owned.particle_type).cpu().numpy(),
        )

    def frame(self, step: int, owned: Particles, position: Tensor) -> None:
        ids = owned.ids.cpu().numpy()
        truth = np.asarray(self.trajectory.position[self.history + step][ids], dtype=np.float32)
        predicted = position.cpu().numpy()
        self.shard.frame(ids, predicted, truth)
        moving = self.simulator.predicted_mask(owned.particle_type).cpu().numpy()
        self.squared_error += float(((predicted[moving] - truth[moving]).astype(np.float64) ** 2).sum())
        self.predicted_values += float(moving.sum() * predicted.shape[-1])


def _on_chief(processes: Processes, ids: Tensor, rows: Tensor) -> Tensor | None:
    """Every process's ``rows`` placed by their global ``ids``, on rank 0 (None elsewhere)."""
    gathered_ids, gathered = send_rows(torch.zeros_like(ids), [ids, rows], processes.world_size, processes.group)
    if not processes.is_chief:
        return None
    assert gathered_ids is not None and gathered is not None
    placed = gathered.new_empty((len(gathered_ids), *gathered.shape[1:]))
    placed[gathered_ids] = gathered
    return placed


def _recut(
    simulator: LearnedSimulator,
    owned: Particles,
    partition: Partition,
    processes: Processes,
    kind: HaloKind,
    axis: int | None,
    cut: Cut,
    particles: int,
) -> tuple[Partition, Particles, int]:
    """Pieces cut afresh by work, this process's particles after those whose owner changed moved, and how many of
    its particles left.

    Each process weighs its own particles on its piece's graph and bins that work on a coarse grid
    (:func:`.work.work_summary`, one sum): no process builds the whole scene's graph or holds its frame.
    """
    work = _owned_work(simulator, owned, partition, processes)
    centres, cell_work, cell_count = work_summary(owned.sequence[:, -1], work, particles, processes)
    halo_weight = cell_work if kind == "positions" else cell_count  # a halo particle: its edges too, or a node
    partition, _ = partition_for(
        simulator, centres, processes.world_size, kind, axis, cut, weight=cell_work, halo_weight=halo_weight
    )
    owned, moved = _migrate(owned, partition, processes)
    return partition, owned, moved


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
