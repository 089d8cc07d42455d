"""What an evaluation compares and what it finds: candidates, their rollouts, report rows and the report."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..data.trajectory import Trajectory
from ..model.deposit_warning import WarningScore

WALL_HELD = "wall_held_particles"
"""Per case: the particles that left the domain in a learned rollout and were put back by the model's guard."""
WARNING_SCORE = "deposit_warning_score"
"""Per case: the model's deposit warning score of its rollout (log-odds of being more than its
``error_pct`` off)."""
WARNING_FLAG = "deposit_warning_flagged"
"""Per case: 1 where that score reaches the warning's threshold, else 0."""
WARNING_ERROR = "deposit_warning_error_pct"
"""Per case: what a flag warns of, extent or height more than this far off, % (the warning's ``error_pct``)."""

Kind = Literal["learned", "simulator"]


@dataclass(frozen=True)
class Prediction:
    """A candidate's rollout of a case.

    A learned model predicts the case's own particles; a simulator at another
    resolution has its own particles, so it brings their types and start frame.

    Attributes:
        position: (S, N', d) positions of the S frames after the case's C input frames, L
            (a NumPy array or a tensor on any device).
        particle_type: (N',) int64, or None for the case's particles.
        start: (N', d) the frame before the first one, L, or None for the case's last input frame.
        held: see below.
    """

    position: np.ndarray | torch.Tensor
    particle_type: np.ndarray | None = None
    start: np.ndarray | torch.Tensor | None = None
    held: int | None = None
    """Particles a wall held: they left the domain and the rollout guard put them back (None: not guarded)."""


@dataclass(frozen=True)
class Candidate:
    """A way of producing rollouts whose error and run time are reported.

    Attributes:
        name: row label in the report.
        kind: ``learned`` or ``simulator``.
        simulate: case (a test trajectory) -> its rollout; called once per warm-up and repeat, and timed.
        reference: the simulator setting that produced the ground truth (at most one).
        settings: resolution, time step or checkpoint, for the table.
        device: where ``simulate`` computes (synchronised around each timing).
        simulate_batch: cases -> their rollouts in order, computed together; when given,
            the cases are rolled out ``batch`` at a time and each is charged its share of
            the batch's time (the throughput a parametric study gets).
        batch: cases per ``simulate_batch`` call.
        warn: (case, its rollout) -> the model's deposit warning of that rollout, or None where it has none or it
            does not apply (:mod:`gns_framework.model.deposit_warning`).
    """

    name: str
    kind: Kind
    simulate: Callable[[Trajectory], Prediction]
    reference: bool = False
    settings: str = ""
    device: str | None = None
    simulate_batch: Callable[[Sequence[Trajectory]], list[Prediction]] | None = None
    batch: int = 1
    warn: Callable[[Trajectory, Prediction], WarningScore | None] | None = None


@dataclass(frozen=True)
class Entry:
    """One row of the report: a candidate's mean error over the cases and its run time.

    Attributes:
        seconds: mean over cases of the median wall-clock time of one rollout, s.
        spread: mean over cases of (slowest - fastest) repeat, s.
        metrics: metric name -> mean over cases (None when missing), see ``Report.metric_units``.
        mse_per_step: (S,) position MSE per rolled-out frame averaged over cases, or None.
        speedup: reference seconds / these seconds, or None without a reference.
        cases: case key -> that case's metrics (the spread a mean hides: the worst collapse matters).
        rollout_files: per case, in order, the rollout file written for it (``rollout_dir``), or None.
    """

    name: str
    kind: Kind
    settings: str
    device: str
    reference: bool
    seconds: float
    spread: float
    metrics: dict[str, float | None]
    mse_per_step: np.ndarray | None
    speedup: float | None = None
    cases: dict[str, dict[str, float | None]] = field(default_factory=dict)
    rollout_files: tuple[Path | None, ...] = ()


@dataclass(frozen=True)
class Report:
    entries: list[Entry]
    error_metric: str
    num_cases: int
    repeats: int
    warmup: int
    dt: float
    hardware: dict[str, str | int] = field(default_factory=dict)
    metric_units: dict[str, str] = field(default_factory=dict)
    """Name (or family pattern) -> unit and meaning of every metric reported."""
    warnings: tuple[str, ...] = ()
    """What the reader must know before trusting the figures (data outside a model's training envelope)."""

    @property
    def reference(self) -> Entry | None:
        return next((e for e in self.entries if e.reference), None)
