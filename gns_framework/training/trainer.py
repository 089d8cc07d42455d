"""The training loop: noisy one-step training windows, validation, checkpoints, exact resume."""

from __future__ import annotations

import json
import math
import time
import uuid
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml
from torch import Tensor
from tqdm import tqdm

from ..assembly.data import prepare_data
from ..assembly.learned import build_learned_simulator, plugin_versions
from ..assembly.scene import scene_to_dict
from ..config.recipe import Recipe
from ..data.atomic import write_text_atomic
from ..data.batch import ParticleBatch
from ..data.windows import WindowIndex, WindowOrder, window_noise_generator
from ..errors import CheckpointError, DatasetError, GnsError, RecipeError
from ..evaluation.candidates import granular_particle_types
from ..io.checkpoint import (
    make_room_for_a_fresh_start,
    prune_checkpoints,
    resume_point,
    save_checkpoint,
    set_aside_damaged,
)
from ..io.run_folder import RunFolder
from ..model.envelope import measure_envelope
from ..model.loss import masked_acceleration_loss, masked_squared_error_sum
from ..model.noise import random_walk_noise, training_noise_std
from ..plugins import Registry
from ..runtime.device import resolve_device
from ..runtime.activation_memory import set_recompute_activations
from ..runtime.allocator import keep_freed_memory
from ..runtime.deterministic import set_deterministic_sums
from ..runtime.host_sync import avoids_read_backs, read_back
from ..runtime.precision import autocast, backward_precision
from . import distributed
from .distributed import Processes
from .ema import WeightAverage
from .optim import make_optimizer
from .provenance import git_commit
from .rollout_validation import validation_rollout_metrics
from .tracking import JsonlTracker, Tracker



class Trainer:
    """Trains the simulator a recipe describes.

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
        self.device = distributed.start(self.processes, resolve_device(recipe.training.device, "training.device (or --device)"))
        if self.device.type == "cpu":
            # CPU tuning only: on a GPU the host merely batches and launches kernels.
            if recipe.training.threads:
                torch.set_num_threads(recipe.training.threads)
            keep_freed_memory()

        self.data = prepare_data(self.recipe, registry, allow_pickle=allow_pickle)
        if recipe.training.pushforward_steps and self.data.scene.context_size:
            raise RecipeError(None, [("training.pushforward_steps", "push-forward needs data without a per-frame "
                                      "global context (step_context): set it to 0 for this dataset")])
        self.windows = self._training_windows()
        self.order = WindowOrder(len(self.windows), recipe.training.batch_size, recipe.seed, self.rank, self.world_size)
        self.validation_batches = self._validation_batches() if self.processes.is_chief else []
        valid = self.data.valid if self.processes.is_chief and self.data.valid is not None else []
        self.validation_trajectories = [valid[i] for i in range(min(recipe.training.validation_rollouts, len(valid)))]
        self.envelope = (
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
        """What the model is trained on, recorded in every checkpoint (rollouts refuse data outside it)."""

        # Same seed on every rank: identical initial weights (DDP would broadcast rank 0's anyway).
        torch.manual_seed(recipe.seed)
        self.simulator = build_learned_simulator(self.data.scene, self.data.metadata, recipe.model, registry).to(self.device)
        self.model: torch.nn.Module = self.processes.wrap(self.simulator, self.device)
        self.noise_std = training_noise_std(recipe.model, self.data.metadata)
        self.optimizer, self.scheduler = make_optimizer(
            self.simulator.parameters(), recipe.training.optimizer, recipe.training.steps
        )
        decay = recipe.training.ema_decay
        self.ema = WeightAverage(self.simulator, decay) if decay else None
        """The weight average that validation, best.pt and rollouts use (training.ema_decay), or None."""
        self.step = 0
        self.history = uuid.uuid4().hex
        """Id of this run's history (kept across resumes, recorded in each checkpoint): retention prunes only its own."""
        self.best: dict = {"metric": recipe.training.best_metric, "value": math.inf, "step": None}
        """The best validation-rollout score so far and its step (restored on resume)."""
        self.tracker = None
        if self.processes.is_chief:
            self.tracker = tracker if tracker is not None else JsonlTracker(self.run_dir)

    def _training_windows(self) -> WindowIndex:
        """The train split's windows; a split with none is a DatasetError naming the split's file and why."""
        train, history = self.data.train, self.recipe.model.history
        ahead = self.recipe.training.pushforward_steps
        where = f"{self.data.dataset.path} (split train)"
        if len(train) == 0:
            raise DatasetError(f"{where}: holds 0 trajectories: training needs at least one")
        try:
            return WindowIndex(train, history, ahead)
        except ValueError:
            longest = max(t.num_steps for t in train)
            raise DatasetError(
                f"{where}: sequence_length: its {len(train)} trajector{'y has' if len(train) == 1 else 'ies have'} "
                f"at most {longest} frames, and training needs more than model.history"
                f"{' + training.pushforward_steps' if ahead else ''} = {history + ahead}"
            ) from None

    def _validation_batches(self):
        valid, history = self.data.valid, self.recipe.model.history
        reason = "no valid split" if valid is None else "an empty valid split" if len(valid) == 0 else None
        if reason is None:
            try:
                index = WindowIndex(valid, history)
            except ValueError:
                reason = f"no valid trajectory longer than history = {history} frames"
        if reason is not None:
            warnings.warn(
                f"{self.data.dataset.path}: {reason}: training goes on without validation "
                f"(no validation losses or rollouts, no {RunFolder.BEST_CHECKPOINT})",
                stacklevel=3,
            )
            return []
        count = min(self.recipe.training.validation_windows, len(index))
        picks = np.unique(np.linspace(0, len(index) - 1, count).round().astype(int))
        size = self.recipe.training.batch_size
        return [index.batch(picks[i : i + size]) for i in range(0, len(picks), size)]

    def state(self) -> dict:
        """Everything a checkpoint needs to rebuild and resume this run."""
        return {
            "model": self.simulator.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "step": self.step,
            # Training draws its noise from per-window generators seeded by (seed, step, window) on the
            # CPU, so no CUDA generator is ever used: only the CPU one is kept, for completeness.
            "rng": {"torch": torch.get_rng_state()},
            "recipe": self.recipe.resolved(),
            "scene": scene_to_dict(self.data.scene),
            "metadata": self.data.metadata.to_json_dict(),
            "plugins": plugin_versions(self.recipe, self.registry, self.data.scene),
            "best": dict(self.best),
            **({"ema": self.ema.state_dict()} if self.ema is not None else {}),
            "history": self.history,
            **({"envelope": self.envelope.to_dict()} if self.envelope is not None else {}),
        }

    def load_state(self, state: dict, source: str) -> None:
        """Resume from a checkpoint of the same model; anything else is refused with the differences."""
        missing = [k for k in ("optimizer", "scheduler", "rng") if k not in state]
        if missing:
            raise CheckpointError(
                f"{source}: {missing[0]}: missing, so it cannot be trained on: roll it out with `gns rollout`, "
                "or start a new run (--out NEW)"
            )
        saved_model = state["recipe"].get("model", {})
        current = self.recipe.resolved()["model"]
        differing = sorted(k for k in set(saved_model) | set(current) if saved_model.get(k) != current.get(k))
        if differing:
            details = "; ".join(f"model.{k}: checkpoint {saved_model.get(k)!r}, recipe {current.get(k)!r}" for k in differing)
            raise CheckpointError(f"{source}: written for a different model: {details}")
        if state["scene"] != scene_to_dict(self.data.scene):
            raise CheckpointError(f"{source}: scene: written for {state['scene']}, this dataset gives {scene_to_dict(self.data.scene)}")
        try:
            self.simulator.load_state_dict(state["model"])
            self.optimizer.load_state_dict(state["optimizer"])
        except (RuntimeError, ValueError) as exc:
            # A model or optimizer state of another parameter layout, e.g. a processor that has since
            # dropped an unused layer: the weights may still load for rollouts (gns rollout), not for training.
            raise CheckpointError(
                f"{source}: its model or optimizer state does not fit this recipe's parameters; roll it out with "
                f"`gns rollout`, or start a new run (--out NEW): {str(exc).splitlines()[0]}"
            ) from None
        try:
            self.scheduler.load_state_dict(state["scheduler"])
            torch.set_rng_state(state["rng"]["torch"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            field = "rng" if "rng" in str(exc) or isinstance(exc, RuntimeError) else "scheduler"
            raise CheckpointError(f"{source}: {field}: not a state this run can resume ({type(exc).__name__}: {exc})") from None
        if self.ema is not None:
            if "ema" in state:
                try:
                    self.ema.load_state_dict(state["ema"])
                except (KeyError, TypeError, RuntimeError) as exc:
                    raise CheckpointError(f"{source}: ema: not a weight average of this model ({type(exc).__name__}: {exc})") from None
            else:
                # A run that turns the average on when resumed averages from the weights it resumes with.
                self.ema = WeightAverage(self.simulator, self.ema.decay)
        self.step = int(state["step"])
        # A checkpoint written before histories were recorded starts a new one: its folder's older
        # checkpoints, which record none, are then never pruned.
        if isinstance(state.get("history"), str):
            self.history = state["history"]
        if "best" in state and state["best"].get("metric") == self.best["metric"]:
            self.best = dict(state["best"])
        # A checkpoint's CUDA generator states (older checkpoints have them) are ignored: nothing
        # draws from them, and restoring them failed with fewer GPUs visible than when it was written.

    def resume(self, checkpoint: str | Path | None = None) -> Path | None:
        """Resume from ``checkpoint``, or from the newest good one of this run when None.

        Rank 0 reads the checkpoint and sends it to the other ranks, so every rank
        resumes from the same state even while older checkpoints are being pruned.
        A resume that would overwrite or prune a checkpoint of another history is
        refused (resume_point); damaged newer checkpoints are renamed aside once the
        state has loaded, so that this run's checkpoints of their steps never replace them.
        """
        found, error = None, None
        if self.processes.is_chief:
            try:
                found = resume_point(self.checkpoint_dir, checkpoint)
            except GnsError as exc:
                error = exc
        # Every rank must reach the broadcast, so rank 0's error travels with it.
        found, error = self.processes.broadcast((found, error))
        if error is not None:
            raise error
        if found is None:
            return None
        self.load_state(found.state, str(found.path))
        if self.processes.is_chief:
            for path in found.damaged_newer:
                warnings.warn(f"damaged checkpoint {path} kept as {set_aside_damaged(path).name}", stacklevel=2)
        return found.path

    def start_afresh(self, restart: bool = False) -> Path | None:
        """Claim the run folder for a run from step 0; returns where ``restart`` moved earlier checkpoints, if it did.

        A folder holding checkpoints is refused, or with ``restart`` moved aside
        with the earlier MLflow record (make_room_for_a_fresh_start). Rank 0 decides
        and tells the others.
        """
        earlier, error = None, None
        if self.processes.is_chief:
            try:
                earlier = make_room_for_a_fresh_start(self.run, restart)
            except GnsError as exc:
                error = exc
        earlier, error = self.processes.broadcast((earlier, error))
        if error is not None:
            raise error
        return earlier

    def save(self) -> Path | None:
        """Rank 0 writes a checkpoint of the current step; every rank waits until it is on disk."""
        path = None
        if self.processes.is_chief:
            path = save_checkpoint(self.run.checkpoint(self.step), self.state())
            prune_checkpoints(self.checkpoint_dir, self.recipe.training.keep_checkpoints, self.history)
        self.processes.barrier()
        return path

    def train_step(self) -> tuple[Tensor, int]:
        """One optimiser step on this process's windows of the current step.

        The loss is the squared error averaged over the predicted particles of the
        *global* batch (every rank's windows): each rank divides its error sum by the
        all-reduced particle count and multiplies by the world size, which DDP's
        gradient averaging divides out again. So W processes of B windows take
        exactly the step of one process with the same W x B windows, whatever the
        particle counts of the windows.

        Nothing here waits for the device: the batch and its noise are built on the
        host and copied from pinned memory without blocking when training on a GPU,
        and the loss stays a device tensor; :meth:`train` reads it back (the one
        host synchronisation) every step on the CPU and only at logging,
        validation and checkpoint steps on a GPU. The graph builder's edge count is
        the other read-back a step needs (``radius_pairs``).

        Returns:
            the global batch's loss, a float64 scalar tensor on the device, and its
            particle count (both identical on every rank).
        """
        batch = self.windows.batch(self.order.indices(self.step))
        noise = self._training_noise()
        if self.device.type == "cuda":
            batch, noise = batch.pinned(), noise.pin_memory()
        batch = batch.to(self.device)
        unrolled = self._pushforward_steps()
        if unrolled:
            batch = self._pushed_forward(batch, unrolled)
        mask = self.simulator.predicted_mask(batch.particle_type)
        noise = noise.to(self.device, non_blocking=True) * mask[:, None, None]
        precision = self.recipe.training.precision
        with autocast(precision, self.device):
            prediction, target = self.model(batch, noise)
        error_sum = masked_squared_error_sum(prediction.to(target.dtype), target, mask)
        local = torch.stack([error_sum.detach().double(), mask.sum().double()])
        global_error, global_predicted = self.processes.sum(local).unbind()
        predicted = global_predicted.clamp(min=1.0)
        loss = error_sum * self.world_size / predicted.to(error_sum.dtype)
        self.optimizer.zero_grad(set_to_none=True)
        with backward_precision(precision, self.device):
            loss.backward()
        self.optimizer.step()
        if self.ema is not None:
            self.ema.update(self.simulator)
        self.scheduler.step()
        global_particles = sum(self.windows.num_particles(self.order.window_at(p)) for p in self.order.step_positions(self.step))
        self.step += 1
        return global_error / predicted, global_particles

    def _pushforward_steps(self) -> int:
        """k of this step's push-forward, uniform in 0..``training.pushforward_steps``, the same on every rank."""
        most = self.recipe.training.pushforward_steps
        if not most:
            return 0
        return int(np.random.default_rng([self.recipe.seed, 2, self.step]).integers(0, most + 1))

    @torch.no_grad()
    def _pushed_forward(self, batch: ParticleBatch, steps: int) -> ParticleBatch:
        """``batch`` with its inputs rolled ``steps`` on by the model itself, and the true frame after them as target.

        No gradient flows through the unrolled steps (the push-forward trick): the
        model is trained on the inputs its own rollouts produce, as it will meet them,
        at the cost of ``steps`` extra forward passes. Kinematic particles follow their
        true positions.
        """
        truth = torch.cat([batch.next_position[:, None], batch.ahead], dim=1)
        sequence = batch.position_sequence
        for step in range(steps):
            rolled = self.simulator.predict_next_position(replace(batch, position_sequence=sequence), prescribed=truth[:, step])
            sequence = torch.cat([sequence[:, 1:], rolled[:, None]], dim=1)
        return replace(batch, position_sequence=sequence, next_position=truth[:, steps])

    def _training_noise(self) -> Tensor:
        """This process's random-walk noise of the current step on the host, (N, C, d) float32.

        Each window's rows come from its own generator, seeded by (seed, step, the
        window's place in the step's global batch): every rank draws only its own
        windows' noise, and W processes of B windows get exactly the noise of one
        process training on the same W x B windows.
        """
        parts = []
        for position in self.order.positions(self.step):
            slot = position - self.order.step_positions(self.step).start
            window = self.order.window_at(position)
            shape = torch.empty((self.windows.num_particles(window), self.recipe.model.history, self.data.scene.dim))
            parts.append(random_walk_noise(shape, self.noise_std, window_noise_generator(self.recipe.seed, self.step, slot)))
        return torch.cat(parts)

    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """One-step loss and next-position MSE on fixed, noise-free windows of the valid split.

        Of the weight average when the recipe keeps one (what best.pt and rollouts use), else of the weights.
        """
        if not self.validation_batches:
            # Also the case on every rank but 0: validation is rank 0's, on the bare model.
            return {}
        model = self.ema.module if self.ema is not None else self.simulator
        model.eval()
        losses, position_errors = [], []
        for batch in self.validation_batches:
            batch = batch.to(self.device)
            mask = model.predicted_mask(batch.particle_type)
            prediction, target = model(batch, torch.zeros_like(batch.position_sequence))
            losses.append(float(masked_acceleration_loss(prediction, target, mask)))
            next_position = model.integrator.next_position(
                batch.position_sequence, model.output_stats.denormalize(prediction)
            )
            position_errors.append(float(((next_position - batch.next_position)[mask] ** 2).mean()))
        metrics = {"valid_one_step_loss": float(np.mean(losses)), "valid_one_step_position_mse": float(np.mean(position_errors))}
        if self.validation_trajectories:
            metrics.update(
                validation_rollout_metrics(
                    model,
                    self.validation_trajectories,
                    self.data.metadata,
                    granular_particle_types(self.data.scene, self.registry),
                    self.device,
                )
            )
        model.train()
        return metrics

    def keep_if_best(self, metrics: dict[str, float]) -> Path | None:
        """Write ``checkpoints/best.pt`` (and ``best.json``) when ``metrics`` beat the best rollout score so far.

        Only rank 0 validates, so only rank 0 ever writes it; the numbered
        checkpoints' retention never touches it.
        """
        value = metrics.get(self.best["metric"])
        if value is None or not value < self.best["value"]:
            return None
        self.best = {"metric": self.best["metric"], "value": float(value), "step": self.step}
        path = save_checkpoint(self.run.best_checkpoint, self.state())
        write_text_atomic(self.run.best_record, json.dumps(self.best, indent=2) + "\n")
        return path

    def train(self, steps: int | None = None) -> list[float]:
        """Train until ``steps`` (default: the recipe's) total steps; returns this call's losses."""
        total = steps if steps is not None else self.recipe.training.steps
        spec = self.recipe.training
        losses: list[float] = []
        if self.tracker is not None:
            self._track_run()
        bar = tqdm(total=total, initial=self.step, desc="train", unit="step", disable=not self.progress or not self.processes.is_chief)
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
            loss, step_particles = self.train_step()
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
                metrics["lr"] = self.scheduler.get_last_lr()[0]
                window_steps, window_particles, window_started = 0, 0, None
            if validates:
                window_started = None
                metrics.update(self.validate())
                if self.keep_if_best(metrics) is not None:
                    metrics["best_step"] = self.step
            if (validates or (logs and not told)) and not self.progress and self.processes.is_chief and self.step < total:
                # Without a progress bar, a background run still says how long it has to go.
                print(time_to_go(self.step, total, self.step - first_step, time.perf_counter() - started), flush=True)
                told = True
            if metrics and self.tracker is not None:
                self.tracker.log_metrics(metrics, self.step)
            if saves:
                window_started = None
                checkpoint = self.save()
        bar.close()
        if checkpoint is not None and self.tracker is not None:
            self.tracker.log_artifact(checkpoint)
        return losses

    def _track_run(self) -> None:
        """Parameters and resolved recipe of the run, for the tracker (rank 0)."""
        self.tracker.log_params(
            {
                "recipe": self.recipe.resolved(),
                "plugins": plugin_versions(self.recipe, self.registry, self.data.scene),
                "git_commit": git_commit(),
                "world_size": self.world_size,
            }
        )
        recipe_file = self.run.recipe
        write_text_atomic(recipe_file, yaml.safe_dump(self.recipe.resolved(), sort_keys=False))
        self.tracker.log_artifact(recipe_file)

    def close(self, failed: bool = False) -> None:
        if self.tracker is not None:
            self.tracker.close(failed)


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


def synchronize(device: torch.device) -> None:
    """Wait for the work queued on ``device`` (a no-op on the CPU)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _read_losses(unread: list[tuple[int, Tensor]]) -> list[float]:
    """The losses of ``(step, loss)`` pairs as floats, in one read-back; the first non-finite one is an error.

    ``step`` is the step count after the loss's optimiser step, so the loss is that of step ``step - 1``.
    """
    values = read_back(torch.stack([loss for _, loss in unread]))
    for (step, _), value in zip(unread, values):
        if not math.isfinite(value):
            raise FloatingPointError(f"training loss is {value} at step {step - 1}")
    return values
