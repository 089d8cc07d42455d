"""The ``gns invert`` configuration file: what to recover, from which observation, how.

Validated in two passes, every problem of both reported at once with its location:
the schema here (:func:`parse_invert_config`), then what only the trained model and the
observed data can tell (:mod:`gns_framework.inverse.problem`): whether the model has an
input for each unknown, whether the trajectory and frames exist.

Example::

    model: models/sand2d_fast.pt
    observed: {dataset: data/heldout, split: test, trajectory: 0, frames: last}
    unknowns:
      friction: {bounds: [0.4, 1.0], initial: 0.7}
    optimizer: {name: adam, lr: 0.05, iterations: 40}   # starts: 8 searches 8 starting points as one batch
    loss: positions
    checkpoint_every: 10
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ..config.paths import resolve_named_path
from ..config.problems import problems_from
from ..config.yaml_files import load_yaml_mapping
from ..errors import RecipeError

INITIAL_VELOCITY = "initial_velocity"
"""The key of the initial-velocity unknown; every other key under ``unknowns`` names a material property."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ObservedSpec(_Strict):
    """The observed trajectory the unknowns must reproduce."""

    dataset: str = Field(description="dataset folder, in any layout the project reads")
    layout: str | None = Field(None, description="dataset plugin of that folder (default: the model's training layout)")
    split: str = Field("test", description="split holding the observed trajectory")
    trajectory: int = Field(0, ge=0, description="index of the trajectory within the split")
    frames: Literal["last", "all"] | list[int] = Field(
        "last",
        description="observed frames the loss compares: last, all, or a list of frame indices of the trajectory "
        "as the model sees it (after the recipe's frame_stride); each must come after the C input frames",
    )
    held_out: list[int] | None = Field(
        None,
        description="observed frames kept out of the loss: the iterate whose rollout matches them best (by the same "
        "loss) is the one returned; default: the iterate of lowest loss",
    )

    @model_validator(mode="after")
    def _held_out_apart(self) -> ObservedSpec:
        if self.held_out is None:
            return self
        if not self.held_out:
            raise ValueError("held_out: give at least one frame index, or leave it out")
        if self.frames == "all":
            raise ValueError("held_out: frames 'all' leaves no frame to hold out; list the frames the loss compares")
        compared = set(self.frames) if isinstance(self.frames, list) else set()
        shared = sorted(compared & set(self.held_out))
        if shared:
            raise ValueError(
                f"held_out: frames {shared} are also in frames; a held-out frame is not compared by the loss"
            )
        return self


def _check_bounds(low: float, high: float, initial: float | None, what: str, fixed_allowed: bool = False) -> None:
    if not (low < high or (fixed_allowed and low == high)):
        relation = "low <= high" if fixed_allowed else "low < high"
        raise ValueError(f"{what}bounds must be [low, high] with {relation}, got [{low}, {high}]")
    if initial is not None and not low <= initial <= high:
        raise ValueError(f"{what}initial {initial} lies outside its bounds [{low}, {high}]")


class PropertyUnknown(_Strict):
    """A per-particle material property (a model input) of the observed particles."""

    bounds: tuple[float, float] = Field(description="[low, high] the value is searched in")
    initial: float | None = Field(None, description="starting value (default: the middle of the bounds)")
    particle_type: int | None = Field(
        None, ge=0, description="particles whose property is unknown (default: every particle the model moves)"
    )

    @model_validator(mode="after")
    def _initial_within_bounds(self) -> PropertyUnknown:
        _check_bounds(*self.bounds, self.initial, "")
        return self

    @property
    def start(self) -> list[float]:
        return [self.initial if self.initial is not None else 0.5 * (self.bounds[0] + self.bounds[1])]


class VelocityUnknown(_Strict):
    """The initial velocity (m/s per axis) of the particles of one type: their C input frames are rebuilt from it.

    ``p_k = p_0 + v t_k + g t_k^2 / 2`` at ``t_k = k dt`` from the first observed frame
    ``p_0``, with ``g`` the given ``gravity`` (0 by default).
    """

    particle_type: int = Field(ge=0, description="particles that start with the unknown velocity")
    bounds: list[tuple[float, float]] = Field(
        description="[[low, high], ...] per axis, dataset length units per second; low = high fixes a known axis"
    )
    initial: list[float] | None = Field(None, description="starting velocity per axis (default: middle of the bounds)")
    gravity: list[float] | None = Field(
        None,
        description="acceleration per axis (length units per s^2) of these particles during the C input frames: "
        "the scene's gravity for a body in free flight, whose input frames are then exactly ballistic; default 0 "
        "(uniform motion)",
    )

    @model_validator(mode="after")
    def _initial_within_bounds(self) -> VelocityUnknown:
        for name in ("initial", "gravity"):
            value = getattr(self, name)
            if value is not None and len(value) != len(self.bounds):
                raise ValueError(f"{name} has {len(value)} entries but bounds has {len(self.bounds)}")
        for axis, (low, high) in enumerate(self.bounds):
            _check_bounds(low, high, None if self.initial is None else self.initial[axis], f"axis {axis}: ", True)
        return self

    @property
    def start(self) -> list[float]:
        return list(self.initial) if self.initial is not None else [0.5 * (lo + hi) for lo, hi in self.bounds]


class InvertOptimizer(_Strict):
    """How the unknowns are searched; both work on each unknown scaled to [0, 1] over its bounds."""

    name: Literal["adam", "lbfgs"] = Field(
        "adam", description="adam (projected onto the bounds after each step) or lbfgs (SciPy's bounded L-BFGS-B)"
    )
    lr: float = Field(
        0.05, gt=0, description="adam's step size, as a fraction of each unknown's bounds range (lbfgs: unused)"
    )
    iterations: int = Field(40, ge=1, description="optimiser iterations (lbfgs: at most this many)")
    lr_decay: float | None = Field(
        None,
        gt=0,
        le=1,
        description="adam only: factor the step size is multiplied by after each iteration (exponential decay; "
        "0.9 over 30 iterations ends at 4 % of lr); default: a constant step size",
    )
    starts: int = Field(
        1,
        ge=1,
        description="adam only: searches from this many starting points at once, their rollouts stepped as one batch "
        "(the first at the unknowns' initial values, the others spread over the bounds by a Latin hypercube); the "
        "answer is the best iterate of all. A loss with several minima needs them",
    )
    seed: int = Field(0, ge=0, description="seed of the Latin hypercube that spreads the starts after the first")

    @model_validator(mode="after")
    def _decay_needs_adam(self) -> InvertOptimizer:
        if self.lr_decay is not None and self.name != "adam":
            raise ValueError(f"lr_decay: only adam takes a step size ({self.name} chooses its own); remove lr_decay")
        if self.starts > 1 and self.name != "adam":
            raise ValueError(
                f"starts: {self.starts} starts run as one batch, which needs an optimiser that steps each unknown on "
                f"its own gradient (adam); {self.name}'s line search would tie the starts together: use adam or "
                "starts: 1"
            )
        return self


class InvertConfig(_Strict):
    model: str = Field(description="trained checkpoint (gns train, or models/*.pt)")
    observed: ObservedSpec
    unknowns: dict[str, dict[str, Any]] = Field(
        description="what to recover: material property names (e.g. friction) and/or initial_velocity"
    )
    optimizer: InvertOptimizer = InvertOptimizer()
    loss: Literal["positions", "runout", "sinkhorn"] = Field(
        "positions",
        description="positions: MSE over the observed frames; runout: relative runout error at the last observed "
        "frame; sinkhorn: Sinkhorn distance between the final clouds (% of the domain)",
    )
    checkpoint_every: int = Field(
        10, ge=0, description="gradient checkpointing interval in rollout steps (0: keep every step's activations)"
    )
    device: str = Field("cpu", description="cpu, cuda or cuda:N")
    threads: int | None = Field(None, ge=1, description="torch intra-op threads (default: torch's)")

    @model_validator(mode="after")
    def _something_to_recover(self) -> InvertConfig:
        if not self.unknowns:
            raise ValueError(
                "unknowns: name at least one unknown (a material property such as friction, or initial_velocity)"
            )
        return self


def parse_invert_config(
    raw: dict, source: str | Path
) -> tuple[InvertConfig, dict[str, PropertyUnknown | VelocityUnknown]]:
    """The validated config and its typed unknowns; RecipeError lists every schema problem."""
    problems: list[tuple[str, str]] = []
    config = None
    try:
        config = InvertConfig.model_validate(raw)
    except ValidationError as exc:
        problems += problems_from(exc, InvertConfig)
    unknowns: dict[str, PropertyUnknown | VelocityUnknown] = {}
    listed = raw.get("unknowns")
    raw_unknowns: dict = listed if isinstance(listed, dict) else {}
    for name, spec in raw_unknowns.items():
        if not isinstance(spec, dict):
            problems.append((f"unknowns.{name}", f"expected a mapping such as {{bounds: [low, high]}}, got {spec!r}"))
            continue
        kind = VelocityUnknown if name == INITIAL_VELOCITY else PropertyUnknown
        try:
            unknowns[name] = kind.model_validate(spec)
        except ValidationError as exc:
            problems += problems_from(exc, kind, ("unknowns", name))
    if problems:
        raise RecipeError(source, problems)
    assert config is not None  # it validated: no problem
    return config, unknowns


def load_invert_config(path: str | Path) -> tuple[InvertConfig, dict[str, PropertyUnknown | VelocityUnknown]]:
    """The config of ``path``, its ``model`` and ``observed.dataset`` resolved as :func:`resolve_named_path` says."""
    config, unknowns = parse_invert_config(load_yaml_mapping(path), path)
    observed = config.observed.model_copy(update={"dataset": str(resolve_named_path(config.observed.dataset, path))})
    config = config.model_copy(update={"model": str(resolve_named_path(config.model, path)), "observed": observed})
    return config, unknowns
