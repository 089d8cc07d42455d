"""The training loop: the optimisation step, validation and checkpoints in turn, with logging."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Unpack

import numpy as np
import torch
import yaml
from torch import Tensor
from tqdm import tqdm

from ..assembly.learned import plugin_versions
from ..config.recipe import Recipe
from ..data.atomic import write_text_atomic
from ..errors import DatasetError
from ..io.checkpoint import list_checkpoints
from ..moved import formerly_positional
from ..plugins import Registry
from ..runtime.host_sync import avoids_read_backs, read_back
from .ema import WeightAverage
from .parts import RunSources, build_training_parts
from .progress import Deadline, Throughput, time_to_go
from .provenance import git_commit
from .tracking import JsonlTracker, Tracker


class Trainer:
    """Trains the simulator a recipe describes: a loop over its parts.

    :class:`~.step.TrainingStep` does one optimisation step; :class:`~.validation.Validation`
    measures the model and keeps ``best.pt``; :class:`~.checkpoints.Checkpoints` writes
    checkpoints and resumes or fine-tunes the run. :mod:`.parts` builds them from the
    recipe; the trainer runs them in turn and logs.

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

    The parts are attributes (:class:`~.parts.TrainingParts`): ``simulator`` is the bare
    model (checkpoints, validation); ``model`` is what training calls, the DDP wrapper
    when distributed, so its backward averages the gradients over the ranks.
    """

    @formerly_positional("run_dir", "dataset_path", "processes", "tracker", "progress", "allow_pickle", after=3)
    def __init__(
        self,
        recipe: Recipe,
        registry: Registry,
        *,
        tracker: Tracker | None = None,
        progress: bool = True,
        **sources: Unpack[RunSources],
    ):
        parts = build_training_parts(recipe, registry, **sources)
        self.recipe, self.registry, self.run, self.processes = parts.recipe, registry, parts.run, parts.processes
        self.run_dir, self.checkpoint_dir = self.run.root, self.run.checkpoints
        self.rank, self.world_size = self.processes.rank, self.processes.world_size
        self.device, self.data, self.team = parts.device, parts.data, parts.team
        self.windows, self.order, self.noise_std = parts.windows, parts.order, parts.noise_std
        self.simulator, self.model = parts.simulator, parts.model
        self.optimizer, self.scheduler = parts.optimizer, parts.scheduler
        self.optimisation, self.validation, self.checkpoints = parts.optimisation, parts.validation, parts.checkpoints
        self.captured = parts.captured
        self.progress = progress
        self.stopped_by_time = False
        """Whether :meth:`train` stopped at its time limit, before its last step."""
        self.last_validation: dict[str, float] | None = None
        """The metrics of this run's latest validation (:meth:`train` validates at its last step), or None."""
        self.tracker = None
        if self.processes.is_chief:
            self.tracker = tracker if tracker is not None else JsonlTracker(self.run_dir)

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
        loss, particles = (self.captured or self.optimisation)(self.step)
        self.step += 1
        return loss, particles

    def validate(self) -> dict[str, float]:
        """Validation metrics of the weight average when the recipe keeps one (what best.pt and rollouts use), else of
        the weights."""
        return self.validation.measure(self.ema.module if self.ema is not None else self.simulator)

    def keep_if_best(self, metrics: dict[str, float]) -> Path | None:
        """Write ``checkpoints/best.pt`` (and ``best.json``) when ``metrics`` beat the best rollout score so far.

        Only rank 0 reports validation metrics (it validates alone, or split with the
        others under ``training.partitions``), so only rank 0 ever writes it; the numbered
        checkpoints' retention never touches it.
        """
        return self.validation.keep_if_best(metrics, self.step, self.checkpoints.state)

    def train(self, steps: int | None = None, time_limit_s: float | None = None) -> list[float]:
        """Train until ``steps`` (default: the recipe's) total steps, or until ``time_limit_s`` seconds have passed
        (then with a checkpoint of the last step, and ``stopped_by_time`` set); returns this call's losses."""
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
        throughput = Throughput(self.device)
        # Losses still on the device: read back every step on the CPU (it costs nothing there), and on a
        # GPU only at steps that log, validate or checkpoint, so the host never waits for the device otherwise.
        unread: list[tuple[int, Tensor]] = []
        self.simulator.train()
        checkpoint = None
        started, first_step, told = time.perf_counter(), self.step, False
        deadline = Deadline(time_limit_s, self.processes)
        while self.step < total:
            throughput.step_starts()
            try:
                loss, step_particles = self.train_step()
            except DatasetError as error:
                raise self._stopped_by_data(error) from None
            throughput.step_done(step_particles)
            unread.append((self.step, loss))
            logs = self.step % spec.log_every == 0 or self.step == total
            validates = self.step % spec.validate_every == 0 or self.step == total
            saves = self.step % spec.checkpoint_every == 0 or self.step == total or deadline.passed(logs)
            if not avoids_read_backs(self.device) or logs or validates or saves:
                read = _read_losses(unread)
                losses += read
                bar.update(len(read))
                bar.set_postfix(loss=f"{read[-1]:.4g}")
                unread = []
            metrics = {}
            if logs:
                metrics["train_loss"] = float(np.mean(losses[-spec.log_every :]))
                metrics.update(throughput.read())
                metrics["lr"] = float(self.scheduler.get_last_lr()[0])
            if validates:
                throughput.pause()
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
                throughput.pause()
                checkpoint = self.checkpoints.save()
            if deadline.reached:
                break
        self.stopped_by_time = deadline.reached
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
                "plugins": plugin_versions(self.recipe, self.registry, self.data.setup),
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


def _read_losses(unread: list[tuple[int, Tensor]]) -> list[float]:
    """The losses of ``(step, loss)`` pairs as floats, in one read-back; the first non-finite one is an error.

    ``step`` is the step count after the loss's optimiser step, so the loss is that of step ``step - 1``.
    """
    values = read_back(torch.stack([loss for _, loss in unread]))
    for (step, _), value in zip(unread, values, strict=True):
        if not math.isfinite(value):
            raise FloatingPointError(f"training loss is {value} at step {step - 1}")
    return values
