"""The parts of a training run, built from a recipe: what :class:`~.trainer.Trainer` loops over.

One small method per part, in the order each needs the ones before (as torchtune's
recipes set up model, data and optimiser apart from their loop): the processes and
device, the data, the windows and their order, the model, the optimisation step,
validation and checkpoints. The trainer receives them and only runs them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TypedDict, Unpack

import torch

from ..assembly.data import PreparedData, prepare_data
from ..assembly.learned import build_learned_simulator, training_problems
from ..config.recipe import Recipe
from ..contracts import ModelSetup
from ..data.memory import trajectories_kept
from ..data.metadata import DatasetMetadata
from ..data.windows import WindowIndex, WindowOrder
from ..decomposition.validation import partitioned_one_step_errors, partitioned_positions
from ..errors import DatasetError, RecipeError
from ..evaluation.rollout_scores import validation_rollout_scorer
from ..io.run_folder import RunFolder
from ..model.envelope import Envelope, measure_envelope
from ..model.learned_simulator import LearnedSimulator
from ..model.noise import training_noise_std
from ..plugins import Registry
from ..runtime.activation_memory import set_recompute_activations
from ..runtime.allocator import keep_freed_memory
from ..runtime.capture import CaptureError
from ..runtime.compiled import compile_node_side
from ..runtime.deterministic import set_deterministic_sums
from ..runtime.device import resolve_device
from ..runtime.processes import Processes
from ..runtime.teams import team_of
from . import distributed
from .captured_step import CapturedTrainingStep
from .checkpoints import Checkpoints
from .clipping import clip_before_each_update
from .ema import WeightAverage
from .optim import make_optimizer
from .partitioned_step import PartitionedTrainingStep
from .step import TrainingStep
from .validation import Validation, validation_windows


def rolled_window_problems(
    pushforward_steps: int, unrolled_loss_steps: int, context_size: int
) -> list[tuple[str, str]]:
    """(recipe field, why) for rolling training windows on over data whose frames carry a global context.

    Push-forward and the unrolled loss advance a window frame by frame, and the per-frame context
    (``step_context``) is not rolled with it.
    """
    if not context_size:
        return []
    why = "needs data without a per-frame global context (step_context): set it to 0 for this dataset"
    asked = {"training.pushforward_steps": pushforward_steps, "training.unrolled_loss_steps": unrolled_loss_steps}
    return [(field, f"{field.split('.')[1]} {why}") for field, steps in asked.items() if steps]


@dataclass
class TrainingParts:
    """Everything a training run is made of, built by :func:`build_training_parts`.

    Attributes:
        recipe: the recipe, on the dataset the run trains on (``--dataset`` recorded in it).
        run: every path of the run folder.
        processes: this process's place in a torchrun job.
        device: where the model and its windows live.
        data: the opened dataset, its statistics, splits and the scene they give.
        windows: the train split's windows; ``order`` deals them into batches per step and process.
        team: this process's team of one process per piece (``training.partitions``), or None.
        simulator: the bare model (checkpoints, validation); ``model`` is what training calls
            (the DDP wrapper when data-parallel, so its backward averages gradients over ranks).
        noise_std: the random-walk noise std of the inputs, dataset length units per frame.
        optimisation: one optimiser step (:class:`~.step.TrainingStep` or its partitioned twin).
        validation: one-step and rollout validation, keeping ``best.pt``.
        checkpoints: writing, resuming and fine-tuning.
        captured: ``optimisation`` replayed from captures (``training.capture_step``), or None.
    """

    recipe: Recipe
    registry: Registry
    run: RunFolder
    processes: Processes
    device: torch.device
    data: PreparedData
    windows: WindowIndex
    order: WindowOrder
    team: Processes | None
    simulator: LearnedSimulator
    model: torch.nn.Module
    noise_std: float
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    optimisation: TrainingStep
    validation: Validation
    checkpoints: Checkpoints
    captured: CapturedTrainingStep | None = None


class RunSources(TypedDict, total=False):
    """Where a run's parts come from beside the recipe, each as :class:`~.trainer.Trainer` documents it."""

    run_dir: str | Path | None
    dataset_path: str | Path | None
    processes: Processes | None
    allow_pickle: Path | None


def build_training_parts(recipe: Recipe, registry: Registry, **sources: Unpack[RunSources]) -> TrainingParts:
    """The parts of the run ``recipe`` describes."""
    return _Builder(recipe, registry, **sources).build()


class _Builder:
    """Builds :class:`TrainingParts`, one method per part."""

    def __init__(self, recipe, registry, run_dir=None, dataset_path=None, processes=None, allow_pickle=None):
        self.recipe: Recipe = recipe.on_dataset(dataset_path) if dataset_path is not None else recipe
        self.registry: Registry = registry
        self.run = RunFolder(Path(run_dir) if run_dir is not None else recipe.run_dir)
        self.processes: Processes = processes if processes is not None else Processes()
        self.allow_pickle = allow_pickle

    def build(self) -> TrainingParts:
        spec = self.recipe.training
        device = self.device()
        refused = training_problems(self.recipe, self.registry)
        if refused:
            raise RecipeError(None, refused)
        data, shapes = self.data()
        windows = self.windows(data, shapes)
        team = self.team()
        order = self.order(windows, team)
        envelope = self.envelope(data)
        # Same seed on every rank: identical initial weights (DDP would broadcast rank 0's anyway).
        torch.manual_seed(self.recipe.seed)
        simulator = build_learned_simulator(data.setup, data.metadata, self.recipe.model, self.registry).to(device)
        model = simulator if team is not None else self.processes.wrap(simulator, device)
        noise_std = training_noise_std(self.recipe.model, data.metadata)
        optimizer, scheduler = make_optimizer(simulator.parameters(), spec.optimizer, spec.steps)
        if spec.optimizer.clip_grad_norm is not None:
            clip_before_each_update(optimizer, spec.optimizer.clip_grad_norm)
        step_kind = TrainingStep if team is None else partial(PartitionedTrainingStep, team=team)
        optimisation = step_kind(
            simulator,
            model,
            windows,
            order,
            noise_std,
            optimizer,
            scheduler,
            WeightAverage(simulator, spec.ema_decay) if spec.ema_decay else None,
            self.processes,
            device,
            seed=self.recipe.seed,
            pushforward_steps=spec.pushforward_steps,
            unrolled_loss_steps=spec.unrolled_loss_steps,
            precision=spec.precision,
        )
        if spec.compile_node_side:  # after the weight average copied it: a copy would call the original's graphs
            compile_node_side(simulator)
        if spec.capture_step and team is not None:
            raise CaptureError("training.capture_step: not with training.partitions (a captured step cannot exchange)")
        captured = CapturedTrainingStep(optimisation) if spec.capture_step else None
        validation = self.validation(data, device, team)
        checkpoints = Checkpoints(
            self.recipe,
            self.registry,
            data,
            simulator,
            optimizer,
            scheduler,
            optimisation,
            validation,
            self.processes,
            self.run,
            envelope,
        )
        return TrainingParts(
            self.recipe,
            self.registry,
            self.run,
            self.processes,
            device,
            data,
            windows,
            order,
            team,
            simulator,
            model,
            noise_std,
            optimizer,
            scheduler,
            optimisation,
            validation,
            checkpoints,
            captured,
        )

    def device(self) -> torch.device:
        """Joins the process group (when distributed) and sets the process-wide switches the recipe asks for."""
        spec = self.recipe.training
        set_recompute_activations(spec.recompute_activations)
        set_deterministic_sums(spec.deterministic)
        device = distributed.start(self.processes, resolve_device(spec.device, "training.device (or --device)"))
        if device.type == "cpu":
            # CPU tuning only: on a GPU the host merely batches and launches kernels.
            if spec.threads:
                torch.set_num_threads(spec.threads)
            keep_freed_memory()
        return device

    def data(self) -> tuple[PreparedData, list[tuple[int, int]]]:
        """The dataset, and each train trajectory's (frames, particles).

        dataset.memory: a process of several keeps a few trajectories, and rank 0 alone
        reads the whole train split once, for the statistics and scene every rank needs.
        """
        keep = trajectories_kept(self.recipe.dataset.memory, self.processes.world_size)
        read: list[PreparedData] = []

        def derive() -> tuple[DatasetMetadata, ModelSetup, list[tuple[int, int]]]:
            read.append(prepare_data(self.recipe, self.registry, allow_pickle=self.allow_pickle, keep=keep))
            return read[0].metadata, read[0].setup, [(t.num_steps, t.num_particles) for t in read[0].train]

        metadata, scene, shapes = distributed.from_chief(self.processes, derive)
        data = read[0] if read else prepare_data(self.recipe, self.registry, self.allow_pickle, keep, (metadata, scene))
        spec = self.recipe.training
        problems = rolled_window_problems(spec.pushforward_steps, spec.unrolled_loss_steps, data.setup.context_size)
        if problems:
            raise RecipeError(None, problems)
        return data, shapes

    def windows(self, data: PreparedData, shapes: list[tuple[int, int]]) -> WindowIndex:
        """The train split's windows; a split with none is a DatasetError naming the split's file and why."""
        train, history = data.train, self.recipe.model.history
        ahead = self.recipe.training.pushforward_steps + self.recipe.training.unrolled_loss_steps
        where = f"{data.dataset.path} (split train)"
        if len(train) == 0:
            raise DatasetError(f"{where}: holds 0 trajectories: training needs at least one")
        try:
            return WindowIndex(train, history, ahead, shapes)
        except ValueError:
            longest = max(frames for frames, _ in shapes)
            raise DatasetError(
                f"{where}: sequence_length: its {len(train)} trajector{'y has' if len(train) == 1 else 'ies have'} "
                f"at most {longest} frames, and training needs more than model.history"
                f"{' + training.pushforward_steps + training.unrolled_loss_steps' if ahead else ''} = {history + ahead}"
            ) from None

    def team(self) -> Processes | None:
        """This process's team when scenes are split over processes (``training.partitions``), else None.

        Refused unless the processes form teams of one per piece, data-parallel over the teams.
        """
        pieces, world_size = self.recipe.training.partitions, self.processes.world_size
        if pieces > 1 and world_size % pieces:
            raise RecipeError(
                None,
                [
                    (
                        "training.partitions",
                        f"{pieces} pieces need a multiple of {pieces} processes (teams of one process per "
                        f"piece, data-parallel over the teams), but WORLD_SIZE is {world_size}: launch as "
                        f"torchrun --nproc-per-node {pieces} -m gns_framework.cli train",
                    )
                ],
            )
        return team_of(self.processes, pieces) if pieces > 1 else None

    def order(self, windows: WindowIndex, team: Processes | None) -> WindowOrder:
        """Batches per step and replica: every process of a team takes its team's windows."""
        pieces, rank, world_size = self.recipe.training.partitions, self.processes.rank, self.processes.world_size
        replicas, replica = (world_size // pieces, rank // pieces) if team is not None else (world_size, rank)
        return WindowOrder(len(windows), self.recipe.training.batch_size, self.recipe.seed, replica, replicas)

    def envelope(self, data: PreparedData) -> Envelope | None:
        """What the model is trained on, recorded in every checkpoint (rollouts refuse data outside it); rank 0's."""
        if not self.processes.is_chief:
            return None
        materials = {t: self.registry.material_by_type(t).name for t in data.setup.particle_types}
        return measure_envelope(data.metadata, data.train, data.setup, materials, self.recipe.dataset.frame_stride)

    def validation(self, data: PreparedData, device: torch.device, team: Processes | None) -> Validation:
        """Fixed one-step windows and the first ``validation_rollouts`` valid trajectories, on the bare model.

        Data-parallel, validation is rank 0's and the other ranks get an empty one. With the
        scenes split (``training.partitions``) every process of rank 0's team validates its
        piece and rank 0 reports (:mod:`gns_framework.decomposition.validation`): a scene too
        large for one device is validated as it is trained. The other teams get an empty one.
        """
        spec, valid = self.recipe.training, data.valid
        batches, trajectories = [], []
        if self.processes.is_chief or (team is not None and self.processes.rank < spec.partitions):
            batches = validation_windows(
                valid, self.recipe.model.history, spec.validation_windows, spec.batch_size, str(data.dataset.path)
            )
            if batches:
                assert valid is not None  # windows come only from a valid split
                trajectories = [valid[i] for i in range(min(spec.validation_rollouts, len(valid)))]
        if team is None:
            score = validation_rollout_scorer(self.registry, data.setup, data.metadata, device)
            return Validation(batches, trajectories, score, spec.best_metric, self.run, device)
        split = partitioned_positions(team, device)
        score = validation_rollout_scorer(self.registry, data.setup, data.metadata, device, positions=split)
        return Validation(
            batches,
            trajectories,
            score,
            spec.best_metric,
            self.run,
            device,
            one_step=partial(partitioned_one_step_errors, processes=team),
            reports=self.processes.is_chief,
        )
