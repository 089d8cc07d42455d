"""The run's checkpoints: what one holds, writing it, and taking a run up again from one.

A checkpoint holds everything a run needs to go on exactly where it stopped (weights,
optimiser, learning-rate schedule, step, random state, best validation score, weight
average) and what the model was built from (recipe, scene, metadata, plugin versions,
the envelope of data it was trained on, which rollouts enforce). Rank 0 reads and
writes; the other ranks receive what it read, so every rank holds the same state.
"""

from __future__ import annotations

import uuid
import warnings
from pathlib import Path

import torch

from ..assembly.data import PreparedData
from ..assembly.learned import plugin_versions
from ..assembly.scene import scene_to_dict
from ..config.recipe import ModelSpec, Recipe
from ..errors import CheckpointError, GnsError
from ..io.checkpoint import (
    load_checkpoint,
    make_room_for_a_fresh_start,
    prune_checkpoints,
    resume_point,
    save_checkpoint,
    set_aside_damaged,
)
from ..io.run_folder import RunFolder
from ..model.envelope import Envelope
from ..model.learned_simulator import LearnedSimulator
from ..plugins import Registry
from ..runtime.processes import Processes
from .ema import WeightAverage
from .step import TrainingStep
from .validation import Validation


class Checkpoints:
    """Writes a run's checkpoints, and resumes it or starts it from a trained model.

    Args:
        recipe, registry, data: what the model was built from (recorded in each
            checkpoint, and compared with a checkpoint resumed or fine-tuned from).
        simulator, optimizer, scheduler: what training changes.
        optimisation: the step room, whose weight average is saved and restored.
        validation: the validation room, whose best score is saved and restored.
        processes: this process's place in a torchrun job.
        run: the run folder.
        envelope: what the model is trained on (rank 0's; None on the other ranks).

    Attributes:
        step: optimiser steps taken (set by :meth:`resume`).
        history: id of this run's history, kept across resumes: retention prunes only its own checkpoints.
        initialized_from: the trained checkpoint (path and step) this run was fine-tuned from, or None.
    """

    def __init__(
        self,
        recipe: Recipe,
        registry: Registry,
        data: PreparedData,
        simulator: LearnedSimulator,
        optimizer: torch.optim.Optimizer,
        scheduler,
        optimisation: TrainingStep,
        validation: Validation,
        processes: Processes,
        run: RunFolder,
        envelope: Envelope | None,
    ):
        self.recipe, self.registry, self.data = recipe, registry, data
        self.simulator, self.optimizer, self.scheduler = simulator, optimizer, scheduler
        self.optimisation, self.validation = optimisation, validation
        self.processes, self.run, self.envelope = processes, run, envelope
        self.step = 0
        self.history = uuid.uuid4().hex
        self.initialized_from: dict | None = None

    def state(self) -> dict:
        """Everything a checkpoint needs to rebuild and resume this run."""
        ema = self.optimisation.ema
        return {
            "model": self.simulator.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "step": self.step,
            # Training draws its noise from per-window generators seeded by (seed, step, window) on the
            # CPU, so no CUDA generator is ever used: only the CPU one is kept, for completeness.
            "rng": {"torch": torch.get_rng_state()},
            "recipe": self.recipe.resolved(),
            "scene": scene_to_dict(self.data.setup),
            "metadata": self.data.metadata.to_json_dict(),
            "plugins": plugin_versions(self.recipe, self.registry, self.data.setup),
            "best": dict(self.validation.best),
            **({"ema": ema.state_dict()} if ema is not None else {}),
            "history": self.history,
            **({"initialized_from": self.initialized_from} if self.initialized_from is not None else {}),
            **({"envelope": self.envelope.to_dict()} if self.envelope is not None else {}),
        }

    def save(self) -> Path | None:
        """Rank 0 writes a checkpoint of the current step; every rank waits until it is on disk."""
        path = None
        if self.processes.is_chief:
            path = save_checkpoint(self.run.checkpoint(self.step), self.state())
            prune_checkpoints(self.run.checkpoints, self.recipe.training.keep_checkpoints, self.history)
        self.processes.barrier()
        return path

    def load_state(self, state: dict, source: str) -> None:
        """Resume from a checkpoint of the same model; anything else is refused with the differences."""
        missing = [k for k in ("optimizer", "scheduler", "rng") if k not in state]
        if missing:
            raise CheckpointError(
                f"{source}: {missing[0]}: missing, so it cannot be trained on: roll it out with `gns rollout`, "
                "or start a new run (--out NEW)"
            )
        self.check_same_model(state, source)
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
            raise CheckpointError(
                f"{source}: {field}: not a state this run can resume ({type(exc).__name__}: {exc})"
            ) from None
        ema = self.optimisation.ema
        if ema is not None:
            if "ema" in state:
                try:
                    ema.load_state_dict(state["ema"])
                except (KeyError, TypeError, RuntimeError) as exc:
                    raise CheckpointError(
                        f"{source}: ema: not a weight average of this model ({type(exc).__name__}: {exc})"
                    ) from None
            else:
                # A run that turns the average on when resumed averages from the weights it resumes with.
                self.optimisation.ema = WeightAverage(self.simulator, ema.decay)
        self.step = int(state["step"])
        # A checkpoint written before histories were recorded starts a new one: its folder's older
        # checkpoints, which record none, are then never pruned.
        if isinstance(state.get("history"), str):
            self.history = state["history"]
        self.validation.restore_best(state.get("best"))
        if isinstance(state.get("initialized_from"), dict):
            self.initialized_from = state["initialized_from"]
        # A checkpoint's CUDA generator states (older checkpoints have them) are ignored: nothing
        # draws from them, and restoring them failed with fewer GPUs visible than when it was written.

    def check_same_model(self, state: dict, source: str, fine_tuning: bool = False) -> None:
        """Refuse a checkpoint of another model (recipe's model section) or scene, naming every difference.

        When ``fine_tuning``, the fields that only shape training (``ModelSpec.TRAINING_ONLY``, the
        training noise) may differ; a resumed run must match in every field.
        """
        saved_model = state["recipe"].get("model", {})
        current = self.recipe.resolved()["model"]
        # The radius the model uses is the scene's (the recipe's, else the data's default): compared there, so
        # a recipe that spells out the radius its checkpoint took from the data is the same model.
        free = {"connectivity_radius"} | (ModelSpec.TRAINING_ONLY if fine_tuning else set())
        differing = sorted(
            k for k in set(saved_model) | set(current) if k not in free and saved_model.get(k) != current.get(k)
        )
        if differing:
            details = "; ".join(
                f"model.{k}: checkpoint {saved_model.get(k)!r}, recipe {current.get(k)!r}" for k in differing
            )
            raise CheckpointError(f"{source}: written for a different model: {details}")
        if state["scene"] != scene_to_dict(self.data.setup):
            raise CheckpointError(
                f"{source}: scene: written for {state['scene']}, this dataset gives {scene_to_dict(self.data.setup)}"
            )

    def initialize_from(self, checkpoint: str | Path) -> int:
        """Fine-tuning: start this run at step 0 from a trained model's weights; returns that model's step.

        The weights are the checkpoint's weight average when it keeps one (what its
        rollouts use), else its weights, with its normalisation statistics (the weights
        were learned against them). The optimiser, the learning-rate schedule, the
        best-checkpoint record and this run's weight average start afresh. The
        checkpoint must be of the same model (the recipe's ``model`` section, but for
        its training noise, which a fine-tuning may change) and scene
        (particle types, bounds, connectivity radius): anything else is refused, naming
        each difference. The source is recorded in every checkpoint (``initialized_from``),
        and the recorded envelope joins the checkpoint's to this data's (:meth:`Envelope.union`).
        """
        path = Path(checkpoint)
        state = None
        error = None
        if self.processes.is_chief:
            try:
                state = load_checkpoint(path)  # refuses a file without recipe, scene, model or step
                self.check_same_model(state, str(path), fine_tuning=True)
            except GnsError as exc:
                error = exc
        # Rank 0 reads; every rank starts from the same weights.
        state, error = self.processes.broadcast((state, error))
        if error is not None:
            raise error
        weights = state["ema"]["model"] if isinstance(state.get("ema"), dict) else state["model"]
        try:
            self.simulator.load_state_dict(weights)
        except RuntimeError as exc:
            raise CheckpointError(
                f"{path}: its weights do not fit this recipe's parameters: {str(exc).splitlines()[0]}"
            ) from None
        if self.optimisation.ema is not None:
            self.optimisation.ema = WeightAverage(self.simulator, self.optimisation.ema.decay)
        if self.envelope is not None and isinstance(state.get("envelope"), dict):
            # The model was trained on both datasets: it may roll out what either held.
            try:
                self.envelope = self.envelope.union(Envelope.from_dict(state["envelope"]))
            except (TypeError, ValueError) as exc:
                raise CheckpointError(f"{path}: envelope: cannot be joined with this data's ({exc})") from None
        self.initialized_from = {"checkpoint": str(path), "step": int(state["step"])}
        return self.initialized_from["step"]

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
                found = resume_point(self.run.checkpoints, checkpoint)
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
