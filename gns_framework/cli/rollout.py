"""``gns rollout``: roll a trained simulator out on a dataset split and save it with the ground truth.

Every rollout is guarded (recipe ``rollout.guard``, or ``--on-violation`` and
``--guard-margin``): a diverging one stops with an error naming the step, the
particles and the cause, and nothing is written for it; under ``clamp`` the clamped
rollout is written and every clamp is reported on stderr.

Data outside what the model was trained on (its envelope) is refused before any
rollout, each quantity named; ``--outside-envelope`` rolls out anyway and records
the warning in every rollout file's metadata and the MLflow run.

A model that carries a deposit warning (:mod:`gns_framework.model.deposit_warning`)
scores every rollout of sand that runs to its trajectory's end: the score is printed
with the rollout and kept in its file's metadata (``deposit_warning``), and a flagged
scene ("may be more than 15 % off") is reported on stderr. Partitioned rollouts are
not scored.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..assembly.data import open_dataset
from ..assembly.trained import load_trained
from ..data.in_parts import scene_in_parts
from ..data.metadata import DatasetMetadata
from ..data.trajectory import Trajectory
from ..decomposition.rollout import RolloutOptions, WrittenRollout, sharded_rollout
from ..errors import DatasetError, GnsError
from ..evaluation.candidates import granular_particle_types
from ..io.rollout_file import write_rollout
from ..io.run_folder import RunFolder
from ..io.sharded_rollout import SUFFIX, is_sharded_rollout
from ..model.batched_rollout import rollout_batch
from ..model.capacity_classes import CaptureClasses
from ..model.learned_simulator import LearnedSimulator
from ..model.rollout import rollout
from ..model.rollout_guard import RolloutGuard, held_particles
from ..outputs import MARKER, check_folder, claim_folder
from ..plugins import load_registry
from ..runtime.compiled import compile_node_side
from ..runtime.device import resolve_device
from ..runtime.precision import PRECISIONS
from ..runtime.processes import Processes
from ..runtime.teams import team_of
from ..safe_names import ensure_inside, require_component, safe_component
from ..training.distributed import from_chief, processes_from_environment, start, stop
from ..training.mlflow_tracker import log_to_recorded_run
from .arguments import (
    add_allow_pickle,
    add_overwrite,
    non_negative_float,
    non_negative_int,
    positive_int,
    ratio_above_one_or_never,
)
from .envelope_option import add_outside_envelope, enforce_envelope


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="checkpoint file written by gns train")
    parser.add_argument("--dataset", type=Path, help="dataset folder (default: the one the model was trained on)")
    add_allow_pickle(parser)
    parser.add_argument("--split", help="split to roll out (default: the recipe's rollout.split)")
    parser.add_argument("--steps", type=positive_int, help="steps per rollout (default: to the end of each trajectory)")
    parser.add_argument("--trajectories", type=positive_int, help="how many trajectories (default: all)")
    parser.add_argument("--out", type=Path, help="output folder (default: <run>/rollouts)")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument(
        "--on-violation",
        choices=("stop", "clamp"),
        help="on NaN/Inf or particles beyond the margin: stop, or clamp and report "
        "(default: rollout.guard.on_violation)",
    )
    parser.add_argument(
        "--guard-margin",
        type=non_negative_float,
        metavar="DISTANCE",
        help="how far a particle may pass a wall, dataset length units (default: rollout.guard.margin)",
    )
    parser.add_argument(
        "--precision",
        choices=PRECISIONS,
        default="float32",
        help="dtype of the model's matrix products: tf32 uses CUDA tensor cores for float32 (float32 on CPUs); "
        "bfloat16 is faster on AMX CPUs and GPUs (default float32)",
    )
    parser.add_argument(
        "--batch",
        type=positive_int,
        default=1,
        metavar="B",
        help="roll out B trajectories of one length at a time as one batch: one graph and one model call per "
        "step for all of them (default 1)",
    )
    parser.add_argument(
        "--partitions",
        type=positive_int,
        default=1,
        metavar="P",
        help="split each scene into P pieces (slabs or blocks) of about equal work, one per process, for "
        "scenes too large for one device: launch as torchrun --nproc-per-node P -m gns_framework.cli rollout ...; "
        "each process writes its particles' frames into its shard of <split>_NNNN.rollout/, which gns render "
        "reads as one rollout; under a multiple of P processes, teams of P roll out the scenes in turn (default 1)",
    )
    parser.add_argument(
        "--partition-axis",
        type=non_negative_int,
        metavar="K",
        help="with --partitions: cut slabs across dimension K (default: the one the particles spread farthest in)",
    )
    parser.add_argument(
        "--cut",
        choices=("auto", "slabs", "blocks"),
        default="auto",
        help="with --partitions: slabs across one dimension, or blocks by recursive bisection (each cut halves the "
        "work across the dimension the particles spread farthest in); auto: whichever leaves the smaller halo at "
        "the first frame (default)",
    )
    parser.add_argument(
        "--rebalance",
        type=ratio_above_one_or_never,
        default=1.25,
        metavar="RATIO",
        help="with --partitions: cut the pieces afresh by work when a process holds more than RATIO times its "
        "share of the particles, as they crowd during a collapse or a runout (no process gathers the frame: only "
        "the particles whose owner changes move); never: keep the first pieces (default 1.25)",
    )
    parser.add_argument(
        "--halo",
        choices=("auto", "positions", "latents"),
        default="auto",
        help="with --partitions: what each process gets of its neighbours' particles: positions as deep as the "
        "receptive field (radius x message-passing steps, any processor that bounds its steps), or node latents "
        "one radius deep after each message-passing step (fewer particles, more exchanges; processors that "
        "exchange latents); auto: latents where the processor exchanges them (default)",
    )
    parser.add_argument(
        "--capture",
        action="store_true",
        help="replay each step from one captured step: a CUDA graph on a GPU, one launch per step instead of "
        "hundreds (on a CPU an emulation, for tests, not faster); the model's graph builder must not wait for the "
        "device (graph builder radius_fixed_capacity; grid_cnn cannot be captured yet); with --batch, each batch is "
        "padded to a capacity class (particles rounded up by at most 25%%) and the batches of a class replay one "
        "capture; not with --partitions",
    )
    parser.add_argument(
        "--compile",
        action="store_true",
        help="compile the model's node side with torch.compile (whole graphs, fused kernels; the first steps pay the "
        "compilation): for long rollouts on a GPU",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_overwrite(parser, "write into --out even when it holds something other than rollouts")
    add_outside_envelope(parser)


def run(args: argparse.Namespace) -> int:
    processes = _processes(args)
    try:
        return _run(args, processes)
    finally:
        stop()


def _processes(args: argparse.Namespace) -> Processes:
    """This process's place in a ``--partitions`` job (torchrun's environment), refused when it does not match."""
    processes = processes_from_environment()
    if args.partitions == 1 and (
        args.partition_axis is not None or args.halo != "auto" or args.cut != "auto" or args.rebalance != 1.25
    ):
        raise GnsError("gns rollout: --partition-axis, --cut, --rebalance and --halo need --partitions P with P > 1")
    if args.cut == "blocks" and args.partition_axis is not None:
        raise GnsError("gns rollout: --partition-axis cuts slabs across one dimension; --cut blocks has no one axis")
    if args.capture and args.partitions > 1:
        raise GnsError("gns rollout: --capture does not combine with --partitions (a piece's particles change)")
    if args.partitions > 1 and args.batch > 1:
        raise GnsError("gns rollout: --partitions and --batch do not combine: a partitioned scene is rolled out alone")
    if processes.world_size % args.partitions:
        raise GnsError(
            f"gns rollout: --partitions {args.partitions} needs {args.partitions} processes, one per piece (or a "
            f"multiple: teams of {args.partitions}, each rolling out its own scenes), but WORLD_SIZE is "
            f"{processes.world_size}: launch it as torchrun --nproc-per-node {args.partitions} "
            "-m gns_framework.cli rollout ..."
        )
    return processes


def _run(args: argparse.Namespace, processes: Processes) -> int:
    registry = load_registry()
    device = start(processes, resolve_device(args.device))
    loaded = load_trained(args.checkpoint, registry, device)
    if args.compile:
        compile_node_side(loaded.simulator)
    spec = loaded.recipe.rollout
    # A scene split over processes is read in parts: a layout that can map its positions maps them (it does when
    # it keeps few trajectories), so that each process reads only its own particles' frames.
    keep = 1 if args.partitions > 1 else None
    dataset = open_dataset(loaded.recipe.dataset, registry, args.dataset, args.allow_pickle, keep=keep)
    dim = dataset.metadata().dim
    if dim != loaded.simulator.setup.dim:
        raise DatasetError(
            f"{dataset.path / 'metadata.json'}: dim: the dataset has dim = {dim} but the model simulates "
            f"dim = {loaded.simulator.setup.dim} ({args.checkpoint})"
        )
    if args.partition_axis is not None and args.partition_axis >= dim:
        raise GnsError(f"gns rollout: --partition-axis {args.partition_axis}: the scene has dimensions 0 to {dim - 1}")
    split_name = require_component(args.split or spec.split, "--split" if args.split else "the recipe's rollout.split")
    trajectories = dataset.split(split_name)
    count = min(len(trajectories), args.trajectories or spec.trajectories or len(trajectories))
    source, allowed = f"{dataset.path} (split {split_name})", args.outside_envelope
    warnings = enforce_envelope(
        loaded, dataset.metadata(), trajectories, allowed, source, "rollout", count=count, processes=processes
    )
    recorded = loaded.metadata.model_copy(update={"outside_envelope": warnings}) if warnings else loaded.metadata
    run = RunFolder.of_checkpoint(args.checkpoint)
    out = args.out or run.rollouts
    # Checked now, claimed with the first file: a rollout that stops writes nothing, not even the marker.
    # Rank 0 alone writes; a refusal there stops every process.
    from_chief(processes, lambda: check_folder(out, "rollout", args.overwrite, own=_only_rollouts))
    errors = []
    guard = RolloutGuard(
        loaded.simulator.setup,
        args.guard_margin if args.guard_margin is not None else spec.guard.margin,
        args.on_violation or spec.guard.on_violation,
    )
    steps = args.steps or spec.steps

    def claim() -> None:
        claim_folder(out, "rollout", args.overwrite, own=_only_rollouts)

    written = _Output(out, safe_component(split_name), recorded, claim)
    job = _Job(loaded.simulator, trajectories, count, steps, device, guard)
    warned = None
    if loaded.deposit_warning is not None:
        granular = granular_particle_types(loaded.simulator.setup, registry)
        warned = loaded.deposit_warning.bound(loaded.simulator.setup, granular, np.asarray(dataset.metadata().bounds))
    for position, (index, result) in enumerate(_rollouts(job, args, processes, written)):
        if result is None:
            continue  # a partitioned rollout is reported by its team's first process
        assessed = None
        if isinstance(result, WrittenRollout):
            path = result.folder
        else:
            if position == 0:
                claim()
            held = held_particles(result.guard_violations)
            assessed = warned(result.predicted, trajectories[index], held) if warned else None
            noted = recorded.model_copy(update={"deposit_warning": assessed.to_dict()}) if assessed else recorded
            path = write_rollout(written.file(index), result, noted)
        clamped = f", clamped at {len(result.guard_violations)} check(s)" if result.guard_violations else ""
        scored = f", deposit warning score {assessed.score:.2f}" if assessed else ""
        print(f"{path}: {result.num_steps} steps, position MSE {result.position_mse:.4g}{clamped}{scored}")
        for violation in result.guard_violations:
            print(f"gns rollout: warning: {path}: clamped {violation.describe()}", file=sys.stderr)
        if assessed is not None and assessed.flagged:
            print(f"gns rollout: warning: {path}: {assessed.describe()}", file=sys.stderr)
        errors.append(result.position_mse)
    if args.partitions > 1:
        # Each team's first process holds its scenes' errors; rank 0 logs the mean over all of them.
        local = torch.tensor([sum(errors), len(errors)], dtype=torch.float64, device=device)
        total, written = processes.sum(local).tolist()
        errors = [total / written] if processes.is_chief and written else []
    if errors:
        tracked = log_to_recorded_run(
            run.root,
            {f"rollout_position_mse_{split_name}": sum(errors) / len(errors)},
            loaded.step,
            tags={"outside_envelope": "; ".join(warnings)} if warnings else None,
        )
        if tracked:
            print(f"logged rollout_position_mse_{split_name} at step {loaded.step} to MLflow run {tracked}")
    return 0


@dataclass(frozen=True)
class _Job:
    """What to roll out: the first ``count`` of ``trajectories``, ``steps`` steps each (None: to their ends)."""

    simulator: LearnedSimulator
    trajectories: Sequence[Trajectory]
    count: int
    steps: int | None
    device: torch.device
    guard: RolloutGuard

    def options(self, args: argparse.Namespace) -> RolloutOptions:
        """The options of this job split over processes (``sharded_rollout``'s)."""
        own = RolloutOptions(steps=self.steps, device=self.device, guard=self.guard, precision=args.precision)
        cutting = RolloutOptions(axis=args.partition_axis, halo=args.halo, cut=args.cut, rebalance=args.rebalance)
        return own | cutting


def _rollouts(job: _Job, args, processes: Processes, output: _Output):
    """(index, rollout) of the job's trajectories, in order; ``--batch`` of one length at a time.

    With ``--partitions`` every process rolls out its piece of each scene and writes its shard
    (:func:`_partitioned_rollouts`); its team's first process gets what was written (None elsewhere).
    """
    if args.partitions > 1:
        yield from _partitioned_rollouts(job, args, processes, output)
        return
    trajectories = job.trajectories
    if args.batch == 1:
        for index in range(job.count):
            yield (
                index,
                rollout(
                    job.simulator,
                    trajectories[index],
                    job.steps,
                    job.device,
                    progress=not args.no_progress,
                    guard=job.guard,
                    precision=args.precision,
                    capture=args.capture,
                ),
            )
        return
    # Consecutive trajectories of one length form a batch, so every scene still runs to its own end.
    capture = CaptureClasses(args.batch) if args.capture else False
    start = 0
    while start < job.count:
        length = trajectories[start].num_steps
        stop = start + 1
        while stop < job.count and stop - start < args.batch and trajectories[stop].num_steps == length:
            stop += 1
        group = [trajectories[i] for i in range(start, stop)]
        results = rollout_batch(
            job.simulator, group, job.steps, job.device, guard=job.guard, precision=args.precision, capture=capture
        )
        yield from zip(range(start, stop), results, strict=True)
        start = stop


@dataclass(frozen=True)
class _Output:
    """Where the rollouts go: ``out/<split>_<index, 4 digits>.npz``, or a folder ``....rollout`` of shards for a
    partitioned scene, written first as a hidden ``.<name>.partial`` beside it; ``claim`` marks ``out`` as gns
    rollout's before anything is written into it."""

    out: Path
    split: str
    metadata: DatasetMetadata
    claim: Callable[[], None]

    def file(self, index: int) -> Path:
        return ensure_inside(self.out / f"{self.split}_{index:04d}.npz", self.out)

    def folder(self, index: int) -> Path:
        return ensure_inside(self.out / f"{self.split}_{index:04d}{SUFFIX}", self.out)

    def partial(self, index: int) -> Path:
        return ensure_inside(self.out / f".{self.folder(index).name}.partial", self.out)


def _partitioned_rollouts(job: _Job, args, processes: Processes, output: _Output):
    """(index, written rollout) of each scene split over a team's processes, each writing its own shard (None
    except on the team's first process).

    Teams take the scenes in turn: in round k, team t rolls out scene ``k * teams + t``. Rank 0
    claims the output folder before the first round. Each scene is written into a hidden partial
    folder, renamed to its name once every team's round went well; when a team's rollout stops,
    every process learns it (the team's own error, or one naming the other team), the partial
    folders are removed, and an output folder this command made and left empty goes too.
    """
    team = team_of(processes, args.partitions)
    teams, mine = processes.world_size // team.world_size, processes.rank // team.world_size
    made = from_chief(processes, lambda: not output.out.exists())
    from_chief(processes, output.claim)
    for first in range(0, job.count, teams):
        index = first + mine
        written, stats, failure, key = None, None, None, ""
        if index < job.count:
            partial = output.partial(index)
            if team.is_chief and partial.exists():
                shutil.rmtree(partial)  # shards of an earlier command that stopped
            team.barrier()
            try:
                scene, options = scene_in_parts(job.trajectories, index), job.options(args)
                key = scene.key
                written, stats = sharded_rollout(job.simulator, scene, team, partial, output.metadata, **options)
            except Exception as exc:
                failure = exc
        # On the processes' device: NCCL reduces CUDA tensors only.
        if processes.sum(torch.tensor([failure is not None], dtype=torch.long, device=job.device)).item():
            if index < job.count and team.is_chief:
                shutil.rmtree(output.partial(index), ignore_errors=True)
            processes.barrier()
            if processes.is_chief and made and not any(p.name != MARKER for p in output.out.iterdir()):
                shutil.rmtree(output.out)
            if failure is not None:
                raise failure
            raise GnsError(
                f"gns rollout: another team's rollout stopped in round {first // teams} (its error says why)"
            )
        if written is None or stats is None or not team.is_chief:
            yield index, None
            continue
        folder = output.folder(index)
        if folder.is_dir():
            shutil.rmtree(folder)  # an earlier result: the claim allowed writing over it
        elif folder.exists():
            folder.unlink()
        written.folder.rename(folder)
        print(
            f"{key or index}: {stats.partition.describe()}, "
            f"halo of {stats.halo_kind} {stats.halo_fraction:.1%} of the particles, "
            f"{stats.migrations} moved between processes, cut afresh {stats.rebalances} times"
        )
        yield index, replace(written, folder=folder)


def _only_rollouts(folder: Path) -> bool:
    """A folder gns rollout wrote before output folders were marked: rollout files (``<split>_NNNN.npz``) and
    sharded rollouts (``<split>_NNNN.rollout`` folders) only."""
    import re

    return all(
        (re.fullmatch(r"[A-Za-z0-9_.-]+_\d{4}\.npz", p.name) and p.is_file())
        or (re.fullmatch(r"[A-Za-z0-9_.-]+_\d{4}\.rollout", p.name) and is_sharded_rollout(p))
        for p in folder.iterdir()
    )
