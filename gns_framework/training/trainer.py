"""The training loop: the optimisation step, validation and checkpoints in turn, with logging."""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import torch
import yaml
from torch import Tensor
from tqdm import tqdm

from ..assembly.data import PreparedData, prepare_data
from ..assembly.learned import build_learned_simulator, plugin_versions, training_problems
from ..evaluation.rollout_scores import validation_rollout_scorer
from ..config.recipe import Recipe
from ..contracts import ModelSetup
from ..data.atomic import write_text_atomic
from ..data.memory import trajectories_kept
from ..data.metadata import DatasetMetadata
from ..data.windows import WindowIndex, WindowOrder
from ..decomposition.validation import partitioned_one_step_errors, partitioned_positions
from ..errors import DatasetError, RecipeError
from ..io.checkpoint import list_checkpoints
from ..io.run_folder import RunFolder
from ..model.envelope import measure_envelope
from ..model.noise import training_noise_std
from ..plugins import Registry
from ..runtime.device import resolve_device, synchronize
from ..runtime.activation_memory import set_recompute_activations
from ..runtime.allocator import keep_freed_memory
from ..runtime.deterministic import set_deterministic_sums
from ..runtime.host_sync import avoids_read_backs, read_back
from . import distributed
from .checkpoints import Checkpoints
from .processes import Processes
from .teams import team_of
from .ema import WeightAverage
from .optim import make_optimizer
from .provenance import git_commit
from .partitioned_step import PartitionedTrainingStep
from .step import TrainingStep
from .tracking import JsonlTracker, Tracker
from .validation import Validation, validation_windows


class Trainer:
    """Trains the simulator a recipe describes: a loop over its rooms.

    :class:`~.step.TrainingStep` does one optimisation step; :class:`~.validation.Validation`
    measures the model and keeps ``best.pt``; :class:`~.checkpoints.Checkpoints` writes
    checkpoints and resumes or fine-tunes the run. The trainer builds them from the
    recipe, runs them in turn and logs.

    Args:
        recipe: validated recipe.
        registry: installed components.
        run_dir: output folder (default: the recipe's ``output_dir`` or ``runs/<name>``).
        dataset_path: overrides ``dataset.path``; the run records it as its recipe's
            (``recipe.yaml``, ``params.json``, checkpoints), so rollouts find the data trained on.
        allow_pickle: the folder the user's ``--allow-pickle`` names; it lets the dataset
            unpickle anything only if it is the dataset's folder.
        processes: this process's place in a torchrun job (one plain process by
            default); when distributed, the process group is joined here and the
            model is wrapped in DistributedDataParallel.
        tracker: where rank 0's metrics go (default: ``<run_dir>/metrics.jsonl``).

    ``simulator`` is the bare model (checkpoints, validation); ``model`` is what
    training calls, the DDP wrapper when distributed, so its forward averages the
    gradients over the ranks.
    """

    def __init__(
        self,
        recipe: Recipe,
        registry: Registry,
        run_dir: str | Path | None = None,
        dataset_path: str | Path | None = None,
        processes: Processes | None = None,
        tracker: Tracker | None = None,
        progress: bool = True,
        allow_pickle: Path | None = None,
    ):
        self.recipe = recipe.on_dataset(dataset_path) if dataset_path is not None else recipe
        self.registry = registry
        self.run = RunFolder(Path(run_dir) if run_dir is not None else recipe.run_dir)
        """Every path of the run folder (:mod:`gns_framework.io.run_folder`)."""
        self.run_dir, self.checkpoint_dir = self.run.root, self.run.checkpoints
        self.processes = processes if processes is not None else Processes()
        self.rank = self.processes.rank
        self.world_size = self.processes.world_size
        self.progress = progress
        set_recompute_activations(recipe.training.recompute_activations)
        set_deterministic_sums(recipe.training.deterministic)
        self.device = distributed.start(
            self.processes, resolve_device(recipe.training.device, "training.device (or --device)")
        )
        if self.device.type == "cpu":
            # CPU tuning only: on a GPU the host merely batches and launches kernels.
            if recipe.training.threads:
                torch.set_num_threads(recipe.training.threads)
            keep_freed_memory()

        refused = training_problems(self.recipe, registry)
        if refused:
            raise RecipeError(None, refused)
        # dataset.memory: a process of several keeps a few trajectories, and rank 0 alone reads the
        # whole train split once, for the statistics and scene every rank needs.
        keep = trajectories_kept(self.recipe.dataset.memory, self.world_size)
        read: list[PreparedData] = []

        def derive() -> tuple[DatasetMetadata, ModelSetup, list[tuple[int, int]]]:
            """What is derived from reading the data: the statistics, the scene, each train trajectory's shape."""
            read.append(prepare_data(self.recipe, registry, allow_pickle=allow_pickle, keep=keep))
            return read[0].metadata, read[0].scene, [(t.num_steps, t.num_particles) for t in read[0].train]

        metadata, scene, shapes = distributed.from_chief(self.processes, derive)
        self.data = read[0] if read else prepare_data(self.recipe, registry, allow_pickle, keep, (metadata, scene))
        if recipe.training.pushforward_steps and self.data.scene.context_size:
            raise RecipeError(
                None,
                [
                    (
                        "training.pushforward_steps",
                        "push-forward needs data without a per-frame "
                        "global context (step_context): set it to 0 for this dataset",
                    )
                ],
            )
        self.windows = self._training_windows(shapes)
        # Split scenes (training.partitions): teams of one process per piece, data-parallel over the teams;
        # every process of a team takes its team's windows.
        partitioned = self._partitioned()
        pieces = recipe.training.partitions
        self.team: Processes | None = team_of(self.processes, pieces) if partitioned else None
        """This process's team of one process per piece (``training.partitions``), or None."""
        replicas, replica = (
            (self.world_size // pieces, self.rank // pieces) if partitioned else (self.world_size, self.rank)
        )
        self.order = WindowOrder(len(self.windows), recipe.training.batch_size, recipe.seed, replica, replicas)
        envelope = (
            measure_envelope(
                self.data.metadata,
                self.data.train,
                self.data.scene,
                {t: registry.material_by_type(t).name for t in self.data.scene.particle_types},
                recipe.dataset.frame_stride,
            )
            if self.processes.is_chief
            else None
        )
        # What the model is trained on, recorded in every checkpoint (rollouts refuse data outside it).

        # Same seed on every rank: identical initial weights (DDP would broadcast rank 0's anyway).
        torch.manual_seed(recipe.seed)
        self.simulator = build_learned_simulator(self.data.scene, self.data.metadata, recipe.model, registry).to(
            self.device
        )
        self.model: torch.nn.Module = (
            self.simulator if partitioned else self.processes.wrap(self.simulator, self.device)
        )
        self.noise_std = training_noise_std(recipe.model, self.data.metadata)
        self.optimizer, self.scheduler = make_optimizer(
            self.simulator.parameters(), recipe.training.optimizer, recipe.training.steps
        )
        decay = recipe.training.ema_decay
        step_kind = TrainingStep if self.team is None else partial(PartitionedTrainingStep, team=self.team)
        self.optimisation = step_kind(
            self.simulator,
            self.model,
            self.windows,
            self.order,
            self.noise_std,
            self.optimizer,
            self.scheduler,
            WeightAverage(self.simulator, decay) if decay else None,
            self.processes,
            self.device,
            seed=recipe.seed,
            pushforward_steps=recipe.training.pushforward_steps,
            precision=recipe.training.precision,
        )
        self.validation = self._validation(partitioned)
        self.checkpoints = Checkpoints(
            self.recipe,
            registry,
            self.data,
            self.simulator,
            self.optimizer,
            self.scheduler,
            self.optimisation,
            self.validation,
            self.processes,
            self.run,
            envelope,
        )
        """Writing checkpoints, resuming, fine-tuning from a trained model (:mod:`.checkpoints`)."""
        self.last_validation: dict[str, float] | None = None
        """The metrics of this run's latest validation (:meth:`train` validates at its last step), or None."""
        self.tracker = None
        if self.processes.is_chief:
            self.tracker = tracker if tracker is not None else JsonlTracker(self.run_dir)

    def _partitioned(self) -> bool:
        """Whether scenes are split over the processes (``training.partitions``); refused unless the processes form
        teams of one per piece."""
        partitions = self.recipe.training.partitions
        if partitions > 1 and self.world_size % partitions:
            raise RecipeError(
                None,
                [
                    (
                        "training.partitions",
                        f"{partitions} pieces need a multiple of {partitions} processes (teams of one process per "
                        f"piece, data-parallel over the teams), but WORLD_SIZE is {self.world_size}: launch as "
                        f"torchrun --nproc-per-node {partitions} -m gns_framework.cli train",
                    )
                ],
            )
        return partitions > 1

    def _training_windows(self, shapes: list[tuple[int, int]]) -> WindowIndex:
        """The train split's windows; a split with none is a DatasetError naming the split's file and why."""
        train, history = self.data.train, self.recipe.model.history
        ahead = self.recipe.training.pushforward_steps
        where = f"{self.data.dataset.path} (split train)"
        if len(train) == 0:
            raise DatasetError(f"{where}: holds 0 trajectories: training needs at least one")
        try:
            return WindowIndex(train, history, ahead, shapes)
        except ValueError:
            longest = max(frames for frames, _ in shapes)
            raise DatasetError(
                f"{where}: sequence_length: its {len(train)} trajector{'y has' if len(train) == 1 else 'ies have'} "
                f"at most {longest} frames, and training needs more than model.history"
                f"{' + training.pushforward_steps' if ahead else ''} = {history + ahead}"
            ) from None

    def _validation(self, partitioned: bool) -> Validation:
        """Fixed one-step windows and the first ``validation_rollouts`` valid trajectories, on the bare model.

        Data-parallel, validation is rank 0's and the other ranks get an empty one. With the
        scenes split (``training.partitions``) every process of rank 0's team validates its
        piece and rank 0 reports (:mod:`gns_framework.decomposition.validation`): a scene too
        large for one device is validated as it is trained. The other teams get an empty one.
        """
        spec, valid = self.recipe.training, self.data.valid
        batches, trajectories = [], []
        if self.processes.is_chief or (partitioned and self.rank < spec.partitions):
            batches = validation_windows(
                valid, self.recipe.model.history, spec.validation_windows, spec.batch_size, str(self.data.dataset.path)
            )
            if batches:
                assert valid is not None  # windows come only from a valid split
                trajectories = [valid[i] for i in range(min(spec.validation_rollouts, len(valid)))]
        scene, metadata = self.data.scene, self.data.metadata
        if not partitioned:
            score = validation_rollout_scorer(self.registry, scene, metadata, self.device)
            return Validation(batches, trajectories, score, spec.best_metric, self.run, self.device)
        assert self.team is not None  # made with the partitions
        split = partitioned_positions(self.team, self.device)
        score = validation_rollout_scorer(self.registry, scene, metadata, self.device, positions=split)
        return Validation(
            batches,
            trajectories,
            score,
            spec.best_metric,
            self.run,
            self.device,
            one_step=partial(partitioned_one_step_errors, processes=self.team),
            reports=self.processes.is_chief,
        )

    @property
    def ema(self) -> WeightAverage | None:
        """The weight average that validation, best.pt and rollouts use (training.ema_decay), or None."""
        return self.optimisation.ema

    @property
    def best(self) -> dict:
        """The best validation-rollout score so far and its step (restored on resume)."""
        return self.validation.best

    @property
    def step(self) -> int:
        """Optimiser steps taken: the checkpoints' record, which resuming sets."""
        return self.checkpoints.step

    @step.setter
    def step(self, value: int) -> None:
        self.checkpoints.step = value

    def train_step(self) -> tuple[Tensor, int]:
        """One optimiser step on this process's windows of the current step (:class:`~.step.TrainingStep`).

        Returns the global batch's loss (a float64 device tensor, which :meth:`train`
        reads back every step on the CPU and only at logging, validation and
        checkpoint steps on a GPU) and its particle count.
        """
        loss, particles = self.optimisation(self.step)
        self.step += 1
        return loss, particles

    def validate(self) -> dict[str, float]:
        """Validation metrics of the weight average when the recipe keeps one (what best.pt and rollouts use), else of the weights."""
        return self.validation.measure(self.ema.module if self.ema is not None else self.simulator)

    def keep_if_best(self, metrics: dict[str, float]) -> Path | None:
        """Write ``checkpoints/best.pt`` (and ``best.json``) when ``metrics`` beat the best rollout score so far.

        Only rank 0 reports validation metrics (it validates alone, or split with the
        others under ``training.partitions``), so only rank 0 ever writes it; the numbered
        checkpoints' retention never touches it.
        """
        return self.validation.keep_if_best(metrics, self.step, self.checkpoints.state)

    def train(self, steps: int | None = None) -> list[float]:
        """Train until ``steps`` (default: the recipe's) total steps; returns this call's losses."""
        total = steps if steps is not None else self.recipe.training.steps
        spec = self.recipe.training
        losses: list[float] = []
        if self.tracker is not None:
            self._track_run()
        bar = tqdm(
            total=total,
            initial=self.step,
            desc="train",
            unit="step",
            disable=not self.progress or not self.processes.is_chief,
        )
        # Throughput over the optimiser steps alone since the last log (not validation or checkpoints),
        # timed from one device synchronisation to the next, so queued GPU work is counted.
        window_steps, window_particles, window_started = 0, 0, None
        # Losses still on the device: read back every step on the CPU (it costs nothing there), and on a
        # GPU only at steps that log, validate or checkpoint, so the host never waits for the device otherwise.
        unread: list[tuple[int, Tensor]] = []
        self.simulator.train()
        checkpoint = None
        started, first_step, told = time.perf_counter(), self.step, False
        while self.step < total:
            if window_started is None:
                synchronize(self.device)
                window_started = time.perf_counter()
            try:
                loss, step_particles = self.train_step()
            except DatasetError as error:
                raise self._stopped_by_data(error) from None
            window_steps, window_particles = window_steps + 1, window_particles + step_particles
            unread.append((self.step, loss))
            logs = self.step % spec.log_every == 0 or self.step == total
            validates = self.step % spec.validate_every == 0 or self.step == total
            saves = self.step % spec.checkpoint_every == 0 or self.step == total
            if not avoids_read_backs(self.device) or logs or validates or saves:
                read = _read_losses(unread)
                losses += read
                bar.update(len(read))
                bar.set_postfix(loss=f"{read[-1]:.4g}")
                unread = []
            metrics = {}
            if logs:
                synchronize(self.device)
                window_seconds = time.perf_counter() - window_started
                metrics["train_loss"] = float(np.mean(losses[-spec.log_every :]))
                metrics["steps_per_s"] = window_steps / window_seconds
                metrics["particles_per_s"] = window_particles / window_seconds
                metrics["lr"] = float(self.scheduler.get_last_lr()[0])
                window_steps, window_particles, window_started = 0, 0, None
            if validates:
                window_started = None
                self.last_validation = self.validate()
                metrics.update(self.last_validation)
                if self.keep_if_best(metrics) is not None:
                    metrics["best_step"] = self.step
            if (
                (validates or (logs and not told))
                and not self.progress
                and self.processes.is_chief
                and self.step < total
            ):
                # Without a progress bar, a background run still says how long it has to go.
                print(time_to_go(self.step, total, self.step - first_step, time.perf_counter() - started), flush=True)
                told = True
            if metrics and self.tracker is not None:
                self.tracker.log_metrics(metrics, self.step)
            if saves:
                window_started = None
                checkpoint = self.checkpoints.save()
        bar.close()
        if checkpoint is not None and self.tracker is not None:
            self.tracker.log_artifact(checkpoint)
        return losses

    def _stopped_by_data(self, error: DatasetError) -> DatasetError:
        """The error that stops training when its data fails mid-run, with a checkpoint of the last whole step.

        Windows, their order and their noise are drawn from the step number, so a
        checkpoint of the step reached resumes exactly. Under several processes the
        others may not have met the error, so none is written: the last one stays.
        """
        if not self.processes.distributed and self.step > 0 and not self.run.checkpoint(self.step).exists():
            last = self.checkpoints.save()
        else:
            written = list_checkpoints(self.run.checkpoints)
            last = written[-1][1] if written else None
        kept = f"{last} is the checkpoint to resume from" if last is not None else "no checkpoint was written yet"
        return type(error)(f"{error}; training stopped at step {self.step}: {kept} (--resume)")

    def _track_run(self) -> None:
        """Parameters and resolved recipe of the run, for the tracker (rank 0)."""
        tracker = self.tracker
        assert tracker is not None  # rank 0, which has one
        tracker.log_params(
            {
                "recipe": self.recipe.resolved(),
                "plugins": plugin_versions(self.recipe, self.registry, self.data.scene),
                "git_commit": git_commit(),
                "world_size": self.world_size,
            }
        )
        recipe_file = self.run.recipe
        write_text_atomic(recipe_file, yaml.safe_dump(self.recipe.resolved(), sort_keys=False))
        tracker.log_artifact(recipe_file)

    def close(self, failed: bool = False, killed: bool = False) -> None:
        if self.tracker is not None:
            self.tracker.close(failed, killed)


def time_to_go(step: int, total: int, done: int, seconds: float) -> str:
    """``step 100 of 40000, 2.31 steps/s: about 4 h 48 min to go``, at the pace since this run (re)started.

    The pace counts everything the loop does (validations and checkpoints too), so it
    is what the clock will show.
    """
    if done < 1 or seconds <= 0:
        return f"step {step} of {total}"
    pace = done / seconds
    left = (total - step) / pace
    minutes = round(left / 60)
    span = f"{minutes // 60} h {minutes % 60} min" if minutes >= 60 else f"{max(minutes, 1)} min"
    return f"step {step} of {total}, {pace:.3g} steps/s: about {span} to go"


def _read_losses(unread: list[tuple[int, Tensor]]) -> list[float]:
    """The losses of ``(step, loss)`` pairs as floats, in one read-back; the first non-finite one is an error.

    ``step`` is the step count after the loss's optimiser step, so the loss is that of step ``step - 1``.
    """
    values = read_back(torch.stack([loss for _, loss in unread]))
    for (step, _), value in zip(unread, values):
        if not math.isfinite(value):
            raise FloatingPointError(f"training loss is {value} at step {step - 1}")
    return values
