"""Validation while training, and keeping the best checkpoint by it.

Two measures, both on the valid split and without noise:

- the one-step loss on fixed windows: how well the model predicts one frame from
  ground-truth inputs;
- rollouts of whole trajectories, scored by the metrics the caller gives
  (:func:`gns_framework.evaluation.rollout_scores.validation_rollout_scorer` builds the
  scorer from the installed metrics measured in validation). A rollout feeds the
  model its own predictions, so it measures what users see (drift, clumping, a
  collapse that does not run out). The one-step loss and the rollout error often
  disagree late in training, which is why the best checkpoint is chosen by a
  rollout metric (``training.best_metric``).

Nothing here knows a metric's name or how it is computed.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from ..data.atomic import write_text_atomic
from ..data.batch import ParticleBatch
from ..data.trajectory import Trajectory
from ..data.windows import WindowIndex
from ..io.checkpoint import save_checkpoint
from ..io.run_folder import RunFolder
from ..model.learned_simulator import LearnedSimulator
from ..model.loss import masked_acceleration_loss
from ..plugin_types import worst_of

RolloutScorer = Callable[[LearnedSimulator, Trajectory], Mapping[str, float]]
"""``(simulator, trajectory) -> {tracked name: error}`` of one full rollout (inf where it diverged)."""


def validation_windows(
    valid: Sequence[Trajectory] | None, history: int, count: int, batch_size: int, where: str
) -> list[ParticleBatch]:
    """``count`` windows spread evenly over the valid split, in batches of ``batch_size``.

    A dataset without usable valid trajectories trains without validation, with a
    warning that names ``where`` (the dataset) and why.
    """
    reason = "no valid split" if valid is None else "an empty valid split" if len(valid) == 0 else None
    if reason is None:
        assert valid is not None
        try:
            index = WindowIndex(valid, history)
        except ValueError:
            reason = f"no valid trajectory longer than history = {history} frames"
    if reason is not None:
        warnings.warn(
            f"{where}: {reason}: training goes on without validation "
            f"(no validation losses or rollouts, no {RunFolder.BEST_CHECKPOINT})",
            stacklevel=4,
        )
        return []
    picks = np.unique(np.linspace(0, len(index) - 1, min(count, len(index))).round().astype(int))
    return [index.batch(picks[i : i + batch_size]) for i in range(0, len(picks), batch_size)]


def rollout_score_summary(
    simulator: LearnedSimulator, trajectories: Sequence[Trajectory], score: RolloutScorer
) -> dict[str, float]:
    """Each tracked error's mean, and its worst (:func:`~gns_framework.plugin_types.worst_of`), over the rollouts.

    The worst is there because a mean over a dozen scenes can stay flat while one
    kind of scene (a long runout in a large box) goes badly wrong. A metric that
    cannot be taken on some scene (a runout without granular particles) is left
    out of that scene's mean and worst, not counted as zero.
    """
    totals: dict[str, list[float]] = {}
    for trajectory in trajectories:
        for name, value in score(simulator, trajectory).items():
            totals.setdefault(name, []).append(float(value))
    summary = {name: float(np.mean(values)) for name, values in totals.items()}
    summary.update({worst_of(name): float(np.max(values)) for name, values in totals.items()})
    return summary


@torch.no_grad()
def one_step_errors(model: LearnedSimulator, batch: ParticleBatch) -> tuple[float, float]:
    """(one-step loss, next-position MSE) of noise-free windows on one process.

    The loss is the squared error of the normalised accelerations summed over dimensions and
    averaged over the predicted particles; the MSE is that of the next positions (L^2),
    averaged over predicted particles and dimensions.

    Shapes: batch (N, C, d) windows with ``next_position`` (N, d).
    """
    mask = model.predicted_mask(batch.particle_type)
    prediction, target = model(batch, torch.zeros_like(batch.position_sequence))
    loss = float(masked_acceleration_loss(prediction, target, mask))
    next_position = model.integrator.next_position(batch.position_sequence, model.output_stats.denormalize(prediction))
    assert batch.next_position is not None, "validation windows have their target"
    return loss, float(((next_position - batch.next_position)[mask] ** 2).mean())


class Validation:
    """Validation of a training run and its best checkpoint.

    Args:
        batches: the fixed one-step windows (:func:`validation_windows`); empty: none.
        trajectories: the valid trajectories rolled out in full at each validation.
        score_rollout: the errors of one rollout (:data:`RolloutScorer`).
        best_metric: the tracked error that picks ``best.pt`` (lower is better).
        run: the run folder ``best.pt`` and ``best.json`` go to.
        device: where the model runs.
        one_step: ``(model, batch) -> (one-step loss, next-position MSE)`` of a batch of
            windows on ``device``; default: :func:`one_step_errors`, on one process.
        reports: whether :meth:`measure` returns the metrics. Processes that validate a
            scene split over several (``training.partitions``) all take part in every
            measure, and only rank 0 reports.

    ``best`` is ``{"metric", "value", "step"}`` of the best score so far; checkpoints
    carry it so that a resumed run keeps beating the same record.
    """

    def __init__(
        self,
        batches: Sequence[ParticleBatch],
        trajectories: Sequence[Trajectory],
        score_rollout: RolloutScorer,
        best_metric: str,
        run: RunFolder,
        device: torch.device,
        one_step: Callable[[LearnedSimulator, ParticleBatch], tuple[float, float]] = one_step_errors,
        reports: bool = True,
    ):
        self.batches = list(batches)
        self.trajectories = list(trajectories)
        self.score_rollout = score_rollout
        self.run = run
        self.device = device
        self.one_step = one_step
        self.reports = reports
        self.best: dict = {"metric": best_metric, "value": math.inf, "step": None}

    @torch.no_grad()
    def measure(self, model: LearnedSimulator) -> dict[str, float]:
        """One-step loss and next-position MSE on the fixed windows, then the rollouts' mean and worst errors.

        Empty when there is nothing to validate on, and on a process that does not report
        (every rank but 0). ``model`` is left in training mode.
        """
        if not self.batches:
            return {}
        model.eval()
        losses, position_errors = [], []
        for batch in self.batches:
            loss, position_error = self.one_step(model, batch.to(self.device))
            losses.append(loss)
            position_errors.append(position_error)
        metrics = {
            "valid_one_step_loss": float(np.mean(losses)),
            "valid_one_step_position_mse": float(np.mean(position_errors)),
        }
        if self.trajectories:
            metrics.update(rollout_score_summary(model, self.trajectories, self.score_rollout))
        model.train()
        return metrics if self.reports else {}

    def keep_if_best(self, metrics: Mapping[str, float], step: int, state: Callable[[], dict]) -> Path | None:
        """Write ``best.pt`` (of ``state()``) and ``best.json`` when ``metrics`` beat the best score so far.

        ``best`` is updated before ``state()`` is called, so the checkpoint records itself as the best.
        """
        value = metrics.get(self.best["metric"])
        if value is None or not value < self.best["value"]:
            return None
        self.best = {"metric": self.best["metric"], "value": float(value), "step": step}
        path = save_checkpoint(self.run.best_checkpoint, state())
        write_text_atomic(self.run.best_record, json.dumps(self.best, indent=2) + "\n")
        return path

    def restore_best(self, saved: Mapping | None) -> None:
        """Take a checkpoint's best record, if it was kept by the same metric (else the record starts afresh)."""
        if saved is not None and saved.get("metric") == self.best["metric"]:
            self.best = dict(saved)
