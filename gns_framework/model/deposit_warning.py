"""A warning, stored with a model, that its deposit of a scene may be far off: scored per rollout.

A learned sand model misses a few scenes' deposits by more than 15 %, and it misses its own training scenes about
as often and in the same kinds of scene. So its training split is a labelled set of its own failures, and a
logistic regression on signals of the scene and the one learned rollout (:mod:`.deposit_signals`) fitted to them
flags held-out scenes it misses (``benchmarks/learned_warning.py`` fits it, chooses its penalty and threshold by
cross-validation on the training scenes alone, measures it on scenes it never saw, and ``--record`` stores it in
a copy of the checkpoint). ``gns rollout`` and ``gns evaluate`` score every sand rollout of a model that carries
one and say which scenes it flags.

Inputs (each a number per rollout; physics in :mod:`.deposit_signals`): the leading front's run share, whether a
wall holds it, the log of its gap to the next obstacle or wall ahead; the tallest column's tan(phi) and aspect over
tan(phi); the log of the sand's particle count; the logs of the energy ratio, of the runout ratio, of the kinetic
energy left at the end and of the fronts' motion then.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Mapping

import numpy as np

from ..contracts import ModelSetup
from ..data.trajectory import Trajectory
from .deposit_signals import DepositSignals, deposit_signals

GAP_CAP = 200.0
"""Particle spacings beyond which an obstacle or wall ahead no longer bears on a front (about 1.7 m at 1/96 m)."""


def _log(value: float, floor: float) -> float:
    """log(value), with ``value`` raised to ``floor`` and an undefined (NaN) value read as 1."""
    return float(np.log(max(value, floor))) if np.isfinite(value) else 0.0


INPUTS: dict[str, Callable[[DepositSignals], float]] = {
    "run share": lambda s: s.leading().share,
    "held by a wall": lambda s: float(s.leading().at_wall),
    "log gap ahead": lambda s: float(np.log1p(np.clip(s.leading().gap, 0.0, GAP_CAP))),
    "tan phi": lambda s: s.signals["tan_phi"],
    "aspect over tan phi": lambda s: s.signals["aspect_over_tan_phi"],
    "log sand particles": lambda s: _log(s.signals["sand_particles"], 1.0),
    "log energy ratio": lambda s: _log(s.signals["energy_ratio"], 1e-3),
    "log runout ratio": lambda s: _log(s.signals["runout_ratio"], 1e-3),
    "log end energy": lambda s: _log(s.signals["end_energy"], 1e-12),
    "log front tail": lambda s: float(np.log1p(max(f.tail for f in s.fronts))),
}
"""The warning's inputs by name, each read from one rollout's signals."""


def warning_inputs(signals: DepositSignals, names: Collection[str] = tuple(INPUTS)) -> np.ndarray:
    """(len(names),) the inputs ``names`` of one rollout's ``signals``."""
    return np.array([INPUTS[name](signals) for name in names], dtype=float)


@dataclasses.dataclass(frozen=True)
class WarningScore:
    """One rollout's warning: its score (log-odds of being more than ``error_pct`` % off), the threshold, the flag."""

    score: float
    threshold: float
    error_pct: float

    @property
    def flagged(self) -> bool:
        return self.score >= self.threshold

    def describe(self) -> str:
        if self.flagged:
            return (
                f"the deposit may be more than {self.error_pct:g} % off in extent or height "
                f"(warning score {self.score:.2f} >= threshold {self.threshold:.2f})"
            )
        return f"warning score {self.score:.2f} below threshold {self.threshold:.2f}"

    def to_dict(self) -> dict[str, float | bool]:
        return {"score": self.score, "threshold": self.threshold, "error_pct": self.error_pct, "flagged": self.flagged}


@dataclasses.dataclass(frozen=True)
class DepositWarning:
    """A fitted warning: which inputs, their standardisation, the weights, the threshold, and what it was fitted on.

    Attributes:
        inputs: names of :data:`INPUTS`, in the weights' order.
        mean, scale: per input, of the training rows.
        weights: per input, log-odds per standard deviation; ``intercept`` the log-odds at the mean.
        threshold: log-odds at or above which a rollout is flagged.
        error_pct: what a flag warns of: extent or height more than this far off, %.
        friction_property: the material property that is tan(phi) (its name in the model's setup).
        fitted_on: the data and the rates measured when it was fitted, in words (for the card and the messages).
    """

    inputs: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    intercept: float
    threshold: float
    error_pct: float = 15.0
    friction_property: str = "friction"
    fitted_on: str = ""

    def __post_init__(self) -> None:
        unknown = [name for name in self.inputs if name not in INPUTS]
        if unknown:
            raise ValueError(f"inputs: unknown {unknown}; the inputs are {list(INPUTS)}")
        sizes = {len(self.inputs), len(self.mean), len(self.scale), len(self.weights)}
        if len(sizes) != 1:
            raise ValueError("inputs, mean, scale and weights: expected one value per input each")
        numbers = [*self.mean, *self.scale, *self.weights, self.intercept, self.threshold, self.error_pct]
        if not all(math.isfinite(v) for v in numbers) or min(self.scale, default=1.0) <= 0:
            raise ValueError("mean, weights, intercept, threshold and error_pct must be finite and every scale > 0")

    def score_signals(self, signals: DepositSignals) -> WarningScore:
        """The warning of one rollout's ``signals``."""
        x = (warning_inputs(signals, self.inputs) - np.array(self.mean)) / np.array(self.scale)
        score = float(x @ np.array(self.weights) + self.intercept)
        return WarningScore(score, self.threshold, self.error_pct)

    def assess(
        self,
        predicted: np.ndarray,
        case: Trajectory,
        history: int,
        setup: ModelSetup,
        granular_types: Collection[int],
        dataset_bounds: np.ndarray,
        held: int = 0,
    ) -> WarningScore | None:
        """The warning of the rollout ``predicted`` (S, N, d), L, of ``case`` from its first ``history`` frames: its
        particles of ``granular_types`` are the sand, its kinematic ones (``setup``) the obstacles, and its box its
        own bounds or ``dataset_bounds`` (d, 2); ``held``: the particles a wall held.

        None where the warning does not apply: a rollout that stops before the case's end (no deposit yet), no
        sand, or no tan(phi) among the setup's material properties.
        """
        predicted = np.asarray(predicted)
        if predicted.shape[0] != case.num_steps - history or not predicted.shape[0]:
            return None
        sand = np.isin(case.particle_type, list(granular_types))
        names = setup.property_names
        if sand.sum() < 2 or case.material_property is None or self.friction_property not in names:
            return None
        friction = np.asarray(case.material_property)[sand, names.index(self.friction_property)]
        fixed = case.position[-1, np.isin(case.particle_type, list(setup.kinematic_types))]
        bounds = np.asarray(case.bounds if case.bounds is not None else dataset_bounds, dtype=float)
        signals = deposit_signals(predicted[:, sand], case.position[history - 1, sand], friction, fixed, bounds, held)
        return self.score_signals(signals)

    def bound(self, setup: ModelSetup, granular_types: Collection[int], dataset_bounds: np.ndarray) -> BoundWarning:
        """This warning with what scoring a model's rollouts of one dataset needs (see :meth:`assess`)."""
        return BoundWarning(self, setup, tuple(granular_types), np.asarray(dataset_bounds, dtype=float))

    def to_dict(self) -> dict:
        """Plain values, as a checkpoint stores them."""
        return {
            "inputs": list(self.inputs),
            "mean": list(self.mean),
            "scale": list(self.scale),
            "weights": list(self.weights),
            "intercept": self.intercept,
            "threshold": self.threshold,
            "error_pct": self.error_pct,
            "friction_property": self.friction_property,
            "fitted_on": self.fitted_on,
        }

    @classmethod
    def from_dict(cls, record: Mapping) -> DepositWarning:
        """The warning of a checkpoint's record; ValueError (naming the field) for anything else."""
        if not isinstance(record, Mapping):
            raise ValueError(f"expected a mapping, got {type(record).__name__}")
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(record) - fields)
        if unknown:
            raise ValueError(f"unknown field(s) {unknown}; the fields are {sorted(fields)}")
        required = [f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING]
        missing = [name for name in required if name not in record]
        if missing:
            raise ValueError(f"missing field(s) {missing}")
        values = dict(record)
        try:
            for name in ("inputs", "mean", "scale", "weights"):
                values[name] = tuple(values[name])
            for name in ("mean", "scale", "weights"):
                values[name] = tuple(float(v) for v in values[name])
            for name in ("intercept", "threshold", "error_pct"):
                if name in values:
                    values[name] = float(values[name])
            for name in ("friction_property", "fitted_on"):
                if name in values and not isinstance(values[name], str):
                    raise TypeError(f"{name}: expected text")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"not numbers where numbers belong ({exc})") from None
        return cls(**values)


@dataclasses.dataclass(frozen=True)
class BoundWarning:
    """A model's deposit warning bound to its setup, the sand's particle types and a dataset's box (d, 2): what
    ``gns rollout`` and ``gns evaluate`` score each rollout with."""

    warning: DepositWarning
    setup: ModelSetup
    granular_types: tuple[int, ...]
    dataset_bounds: np.ndarray

    def __call__(self, predicted: np.ndarray, case: Trajectory, held: int = 0) -> WarningScore | None:
        """:meth:`DepositWarning.assess` of the rollout ``predicted`` (S, N, d) of ``case`` from the setup's history,
        ``held`` particles held by a wall."""
        setup = self.setup
        return self.warning.assess(
            predicted, case, setup.history, setup, self.granular_types, self.dataset_bounds, held
        )
